"""Liveness, readiness, request logging, and recovery from a database outage."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import httpx
import pytest

from cli.ops import embedded
from testkit.scratch import scratch_database
from testkit.server import free_port, running_server


def test_healthz_and_readyz(client) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = client.get("/readyz")
    assert ready.status_code == 200
    assert ready.json()["status"] == "ready"


def test_openapi_docs_served(client) -> None:
    assert client.get("/docs").status_code == 200
    assert "/readyz" in client.get("/openapi.json").json()["paths"]


def test_one_structured_log_line_per_request(client, caplog) -> None:
    caplog.set_level("INFO", logger="ugvmap.request")
    client.get("/healthz?probe=1")
    lines = [r for r in caplog.records if r.name == "ugvmap.request"]
    assert len(lines) == 1
    fields = lines[0].fields
    assert fields["path"] == "/healthz" and fields["status"] == 200
    assert fields["query"] == "probe=1" and fields["duration_ms"] >= 0
    from app.logs import JsonFormatter

    assert json.loads(JsonFormatter().format(lines[0]))["status"] == 200


def _wait_status(url: str, status: int, timeout_s: float = 20.0) -> httpx.Response:
    deadline = time.monotonic() + timeout_s
    while True:
        resp = httpx.get(url, timeout=10)
        if resp.status_code == status or time.monotonic() > deadline:
            return resp
        time.sleep(0.3)


@pytest.mark.slow
def test_readyz_follows_database_outage_without_restart() -> None:
    """A private cluster is stopped under a running server: 503 with a reason, then 200 again."""
    root = Path(tempfile.mkdtemp(prefix="ugvmap-pg-"))
    os.chmod(root, 0o755)
    cluster = embedded.Cluster(root / "postgres", free_port(), "ugvmap")
    try:
        embedded.start(cluster)
        url = f"postgresql://postgres@127.0.0.1:{cluster.port}/ugvmap"
        from app.db import migrate

        migrate.upgrade(url)
        with running_server({"DATABASE_URL": url}) as base:
            assert _wait_status(f"{base}/readyz", 200).status_code == 200
            embedded.stop(cluster)
            down = _wait_status(f"{base}/readyz", 503)
            assert down.status_code == 503
            assert down.json()["code"] == "DatabaseUnavailable"
            assert "database unreachable" in down.json()["message"]
            # Same fault, same answer on every data endpoint (tests/test_error_model.py).
            for path in ("/layers", "/jobs", "/networks/any/route?points=0,0;1,1"):
                resp = httpx.get(f"{base}{path}")
                assert resp.status_code == 503 and resp.headers["retry-after"], path
                assert resp.json()["code"] == "DatabaseUnavailable", path
            embedded.start(cluster)
            assert _wait_status(f"{base}/readyz", 200).status_code == 200
    finally:
        embedded.stop(cluster)
        shutil.rmtree(root, ignore_errors=True)


def test_readyz_503_when_schema_not_migrated(database_url: str) -> None:
    """A reachable but empty database is not ready, and says how to fix it."""
    with scratch_database("ugvmap_empty", migrated=False, base_url=database_url) as url, \
            running_server({"DATABASE_URL": url}) as srv:
        resp = httpx.get(f"{srv}/readyz")
        assert resp.status_code == 503
        assert resp.json()["code"] == "SchemaOutOfDate"
        assert "ugvmap db upgrade" in resp.json()["message"]
