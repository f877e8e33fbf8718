"""A serving process tunes its garbage collector (app.collector) and malloc (app.malloc) once
it starts."""

from __future__ import annotations

import gc
import platform

import pytest
from fastapi.testclient import TestClient

from app import malloc
from app.collector import YOUNG_THRESHOLD
from app.main import create_app


def test_serving_freezes_what_is_loaded_and_collects_less_often() -> None:
    with TestClient(create_app()) as client:
        assert client.get("/healthz").status_code == 200
        assert gc.get_freeze_count() > 0
        assert gc.get_threshold()[0] == YOUNG_THRESHOLD


def test_serving_caps_malloc_arenas(monkeypatch: pytest.MonkeyPatch) -> None:
    """A serving process limits glibc to two malloc arenas (app.malloc) once it starts; the
    call reaches glibc's ``mallopt`` and is accepted (on a glibc system, as CI's is)."""
    calls: list[int] = []
    real = malloc.cap_arenas

    def recorded(arenas: int = malloc.ARENAS) -> bool:
        calls.append(arenas)
        return real(arenas)

    monkeypatch.setattr(malloc, "cap_arenas", recorded)
    with TestClient(create_app()) as client:
        assert client.get("/healthz").status_code == 200
    assert calls == [2]
    assert platform.libc_ver()[0] != "glibc" or real() is True
