"""Batch jobs leave a status row that the API shows while they run and after they end."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from app.db.session import session_scope
from app.jobs.recorder import JobRecorder
from cli.main import main


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
