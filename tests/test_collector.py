"""A serving process tunes its garbage collector once it starts (app.collector)."""

from __future__ import annotations

import gc

from fastapi.testclient import TestClient

from app.collector import YOUNG_THRESHOLD
from app.main import create_app


def test_serving_freezes_what_is_loaded_and_collects_less_often() -> None:
    with TestClient(create_app()) as client:
        assert client.get("/healthz").status_code == 200
        assert gc.get_freeze_count() > 0
        assert gc.get_threshold()[0] == YOUNG_THRESHOLD
