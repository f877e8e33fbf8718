"""Batch jobs leave a status row that the API shows while they run and after they end; a
killed job's row turns failed; /jobs follows its read role and hides server paths."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import session_scope
from app.jobs.recorder import JobRecorder
from app.settings import get_settings
from cli.main import main
from testkit.network_helpers import bearer
from testkit.raster_synth import synthetic_utm, utm_origin
from tests.conftest import REPO


def test_progress_is_visible_while_the_job_transaction_is_open(client) -> None:
    with session_scope(), JobRecorder("test-job", "target-x", {"n": 1}) as job:
        job.progress(0.4, "halfway there")
        seen = client.get(f"/jobs/{job.id}").json()
        assert (seen["status"], seen["progress"], seen["message"]) == (
            "running", 0.4, "halfway there")
    done = client.get(f"/jobs/{job.id}").json()
    assert done["status"] == "succeeded" and done["progress"] == 1
    assert done["finished_at"] >= done["started_at"]


def test_failed_job_records_its_reason(client) -> None:
    with pytest.raises(ValueError, match="broken input"), \
            JobRecorder("test-job", "target-y") as job:
        raise ValueError("broken input")
    row = client.get(f"/jobs/{job.id}").json()
    assert row["status"] == "failed" and row["error"] == "broken input"


def test_cli_ingests_are_recorded(client, tmp_path: Path) -> None:
    roads = tmp_path / "roads.geojson"
    roads.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": "A"},
         "geometry": {"type": "LineString", "coordinates": [[10, 50], [10.001, 50]]}}]}))
    runner = CliRunner()
    assert runner.invoke(main, ["ingest", "network", str(roads), "--network", "jobs-net"]
                         ).exit_code == 0
    bogus = tmp_path / "not-an-image.tif"
    bogus.write_bytes(b"certainly not a TIFF")
    failed = runner.invoke(main, ["ingest", "raster", str(bogus), "--layer", "jobs-layer"])
    assert failed.exit_code == 1
    jobs = client.get("/jobs", params={"limit": 10}).json()["jobs"]
    by_kind = {j["kind"]: j for j in reversed(jobs)}  # newest of each kind (list is newest first)
    assert by_kind["ingest-network"]["status"] == "succeeded"
    assert by_kind["ingest-network"]["target"] == "jobs-net"
    assert by_kind["ingest-raster"]["status"] == "failed"
    assert "not-an-image.tif" in by_kind["ingest-raster"]["error"]
    assert client.get("/layers/jobs-layer").status_code == 404  # nothing half-registered


def test_job_query_errors(client) -> None:
    assert client.get("/jobs/999999999").status_code == 404
    assert client.get("/jobs/0").status_code == 404
    assert client.get("/jobs", params={"status": "nonsense'; DROP TABLE x"}).status_code == 400
    assert client.get("/jobs", params={"limit": 0}).status_code == 422


@contextmanager
def settings_env(monkeypatch: pytest.MonkeyPatch, **values: str) -> Iterator[None]:
    """Run the block with these ``UGVMAP_*`` settings, then restore the defaults."""
    for key, value in values.items():
        monkeypatch.setenv(key, value)
    get_settings.cache_clear()
    try:
        yield
    finally:
        for key in values:
            monkeypatch.delenv(key)
        get_settings.cache_clear()


def _failed_raster_ingest(tmp_path: Path) -> int:
    bogus = tmp_path / "secret-dir" / "not-an-image.tif"
    bogus.parent.mkdir()
    bogus.write_bytes(b"certainly not a TIFF")
    result = CliRunner().invoke(main, ["ingest", "raster", str(bogus), "--layer", "jobs-paths"])
    assert result.exit_code == 1
    with session_scope() as s:
        return s.execute(text("SELECT max(id) FROM ingest_jobs WHERE target = 'jobs-paths'")
                         ).scalar_one()


def test_anonymous_jobs_show_no_absolute_paths(client, tmp_path: Path) -> None:
    job_id = _failed_raster_ingest(tmp_path)
    for response in (client.get("/jobs"), client.get(f"/jobs/{job_id}")):
        assert response.status_code == 200
        assert str(tmp_path) not in response.text and "/secret-dir/" not in response.text
    row = client.get(f"/jobs/{job_id}").json()
    assert row["params"]["sources"] == ["not-an-image.tif"]
    assert "not-an-image.tif" in row["error"] and "worker" not in row
    admin = client.get(f"/jobs/{job_id}", headers=bearer("admin")).json()
    assert admin["params"]["sources"] == [str(tmp_path / "secret-dir" / "not-an-image.tif")]
    assert admin["worker"]


def test_jobs_follow_the_read_role(client, tmp_path: Path,
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    job_id = _failed_raster_ingest(tmp_path)
    with settings_env(monkeypatch, UGVMAP_NETWORK_READ_ROLE="viewer"):
        assert client.get("/jobs").status_code == 401
        assert client.get(f"/jobs/{job_id}").status_code == 401
        viewer = client.get(f"/jobs/{job_id}", headers=bearer("viewer"))
        assert viewer.status_code == 200 and str(tmp_path) not in viewer.text
    with settings_env(monkeypatch, UGVMAP_JOBS_READ_ROLE="admin"):
        assert client.get("/jobs", headers=bearer("editor")).status_code == 403
        assert client.get("/jobs", headers=bearer("admin")).status_code == 200
    assert client.get("/jobs", headers={"Authorization": "Bearer nope"}).status_code == 401


def test_killed_ingest_is_marked_failed(client, tmp_path: Path,
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """A SIGKILLed `ugvmap ingest` stops renewing its lease: its row turns failed within a
    lease instead of staying `running` forever."""
    east, north = utm_origin()
    # Enough work to outlast the lease check by far on an idle machine (5 such images were
    # ingested within the 1.5 s once, and the job was already 'succeeded').
    images = [str(synthetic_utm(tmp_path / f"z{i}.tif", 1500, 1500, 0.3,
                                (east + 450 * i, north))[0]) for i in range(16)]
    slug = f"killed-{uuid.uuid4().hex[:6]}"
    with settings_env(monkeypatch, UGVMAP_JOB_LEASE_S="1"):
        proc = subprocess.Popen([sys.executable, "-m", "cli", "ingest", "raster", *images,
                                 "--layer", slug], cwd=REPO, env=dict(os.environ),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            job = None
            deadline = time.monotonic() + 60
            while job is None and time.monotonic() < deadline:
                rows = client.get("/jobs", params={"status": "running"}).json()["jobs"]
                job = next((j for j in rows if j["target"] == slug), None)
                time.sleep(0.05)
            assert job is not None and proc.poll() is None, "the ingest never showed running"
            time.sleep(1.5)  # a lease's worth of renewals: still alive, still running
            assert client.get(f"/jobs/{job['id']}").json()["status"] == "running"
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
        deadline = time.monotonic() + 10
        while client.get(f"/jobs/{job['id']}").json()["status"] == "running" \
                and time.monotonic() < deadline:
            time.sleep(0.2)
        row = client.get(f"/jobs/{job['id']}").json()
    assert row["status"] == "failed" and "died" in row["error"], row
    assert row["finished_at"] is not None
    assert client.get(f"/layers/{slug}").status_code == 404  # nothing half-registered
    listed = CliRunner().invoke(main, ["jobs", "--status", "failed", "--limit", "50"])
    assert listed.exit_code == 0 and f"{job['id']}\tingest-raster\t{slug}\tfailed" in listed.output
