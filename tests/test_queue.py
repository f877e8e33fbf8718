"""Jobs on the queue: POST /jobs is admin-only and validated, a fanned-out raster ingest
registers its layer exactly once, and survives a worker SIGKILLed mid-task."""

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
from sqlalchemy import create_engine, inspect, text

from app.db import migrate
from app.db.session import get_engine, session_scope
from app.jobs.queue import enqueue
from app.jobs.rows import start_queued
from app.tiles.store import open_store
from cli.main import main
from ingest.queue import raster, tasks
from ingest.queue.worker import make_worker_app
from testkit.network_helpers import bearer
from testkit.raster_synth import synthetic_utm, utm_origin
from testkit.scratch import scratch_database
from tests.conftest import REPO


def sources(folder: Path, n: int, size: int = 600) -> list[str]:
    """``n`` side-by-side synthetic UTM images (one zone each)."""
    east, north = utm_origin()
    return [str(synthetic_utm(folder / f"zone{i}.tif", size, size, 0.3,
                              (east + i * size * 0.3, north))[0]) for i in range(n)]


def scalar(sql: str, **values) -> object:
    with get_engine().connect() as conn:
        return conn.execute(text(sql), values).scalar()


def one(sql: str, **values):
    with get_engine().connect() as conn:
        return conn.execute(text(sql), values).one()


def registered_uris(slug: str) -> set[str]:
    with get_engine().connect() as conn:
        return set(conn.execute(text(
            "SELECT uri FROM raster_sources s JOIN layers l ON l.id = s.layer_id "
            "WHERE l.slug = :s"), {"s": slug}).scalars())


def layer_state(slug: str) -> tuple[int, int]:
    """(version, number of sources) of a layer."""
    with get_engine().connect() as conn:
        return tuple(conn.execute(text(
            "SELECT l.version, count(s.id) FROM layers l LEFT JOIN raster_sources s "
            "ON s.layer_id = l.id WHERE l.slug = :s GROUP BY l.id"), {"s": slug}).one())


def test_post_jobs_needs_an_admin_token(client) -> None:
    body = {"kind": "ingest-network", "params": {"file": "/x.geojson", "network": "n"}}
    before = scalar("SELECT count(*) FROM ingest_jobs")
    anonymous = client.post("/jobs", json=body)
    assert anonymous.status_code == 401 and anonymous.json()["code"] == "Unauthorized"
    assert client.post("/jobs", json=body, headers=bearer("editor")).status_code == 403
    assert client.post("/jobs", json={"kind": "nonsense"}).status_code == 401  # auth first
    assert scalar("SELECT count(*) FROM ingest_jobs") == before


@pytest.mark.parametrize(("body", "field"), [
    ({"kind": "ingest-ipm", "params": {}}, "kind"),
    ({"params": {}}, "kind"),
    ({"kind": "ingest-raster", "params": {"sources": ["rel/x.tif"], "layer": "ok"}},
     "params.sources.0"),
    ({"kind": "ingest-raster", "params": {"sources": [], "layer": "ok"}}, "params.sources"),
    ({"kind": "ingest-raster", "params": {"sources": ["/a.tif"], "layer": "Bad Slug"}},
     "params.layer"),
    ({"kind": "ingest-raster", "params": {"sources": ["/a.tif"], "layer": "ok",
                                          "kind": "movie"}}, "params.kind"),
    ({"kind": "ingest-raster", "params": {"sources": ["/a.tif"], "layer": "ok",
                                          "crs": "EPSG:999999"}}, "params.crs"),
    ({"kind": "ingest-raster", "params": {"sources": ["/a.tif", "/b.tif"], "layer": "ok",
                                          "gcps": "/g.csv"}}, "params"),
    ({"kind": "ingest-network", "params": {"file": "/x.geojson", "network": "n",
                                           "replce": True}}, "params.replce"),
    ({"kind": "ingest-roads", "params": {"layer": "a", "network": "b",
                                         "train_boxes": [[10, 50, 9, 51]]}},
     "params.train_boxes.0"),
    ({"kind": "ingest-roads", "params": {"layer": "a", "network": "b", "k": "nan"}},
     "params.k"),
    ({"kind": "ingest-roads", "params": {"layer": "a", "network": "b",
                                         "rules": {"speed_kph": {"residential": 400}}}},
     "params.rules.speed_kph.residential"),
    ({"kind": "ingest-roads", "params": {"layer": "a", "network": "b",
                                         "rules": {"classes": [{"road_class": "highway"}]}}},
     "params.rules.classes.0.road_class"),
    ({"kind": "ingest-network", "params": ["/x.geojson"]}, "params"),
    ({"kind": "ingest-network", "params": {}, "priority": 9}, "body"),
])
def test_post_jobs_refuses_bad_parameters_before_queueing(client, body: dict,
                                                          field: str) -> None:
    before = scalar("SELECT count(*) FROM ingest_jobs"), scalar(
        "SELECT count(*) FROM procrastinate_jobs")
    response = client.post("/jobs", json=body, headers=bearer("admin"))
    assert response.status_code == 422, response.text
    assert response.json()["code"] == "InvalidValue"
    assert any(k == field or k.startswith(field + ".") for k in response.json()["errors"]), \
        response.json()
    assert (scalar("SELECT count(*) FROM ingest_jobs"),
            scalar("SELECT count(*) FROM procrastinate_jobs")) == before


def test_post_jobs_body_must_be_json(client) -> None:
    admin = bearer("admin")
    assert client.post("/jobs", content=b"{", headers={**admin, "Content-Type":
                                                      "application/json"}).status_code == 400
    assert client.post("/jobs", content=b"x", headers={**admin, "Content-Type":
                                                      "text/plain"}).status_code == 415


def test_post_jobs_queues_the_job_and_its_task(client) -> None:
    response = client.post("/jobs", headers=bearer("admin"), json={
        "kind": "ingest-network", "params": {"file": "/data/roads.geojson", "network": "queued"}})
    assert response.status_code == 202, response.text
    job = response.json()
    assert response.headers["location"] == f"/jobs/{job['id']}"
    assert (job["status"], job["queued"], job["target"], job["params"]["replace"]) == (
        "queued", True, "queued", False)
    task = scalar("SELECT task_name FROM procrastinate_jobs WHERE status = 'todo' "
                  "AND (args->>'job_id')::bigint = :id", id=job["id"])
    assert task == "ugvmap:run_job"
    anonymous = client.get(f"/jobs/{job['id']}").json()
    assert anonymous["params"]["file"] == "roads.geojson" and "worker" not in anonymous


def test_task_names_match_the_blueprint() -> None:
    names = set(make_worker_app().tasks)
    assert {"ugvmap:run_job", raster.WRITE_PART, raster.FINISH} <= names


def test_queued_network_import_commits_with_its_job(database_url: str, tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    roads = tmp_path / "roads.geojson"
    roads.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": "A"},
         "geometry": {"type": "LineString", "coordinates": [[10, 50], [10.001, 50]]}}]}))
    name = f"qnet-{uuid.uuid4().hex[:6]}"
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(main, ["ingest", "network", "roads.geojson", "--network", name,
                                       "--queue"])
    assert result.exit_code == 0 and "queued job" in result.output, result.output
    job_id = int(result.output.split()[2])
    assert scalar("SELECT params->>'file' FROM ingest_jobs WHERE id = :id", id=job_id) == \
        str(roads.resolve())  # workers get an absolute path
    tasks.run_job(job_id)
    tasks.run_job(job_id)  # delivered twice: the second run finds the job done
    row = one("SELECT status, progress, message FROM ingest_jobs WHERE id = :id", id=job_id)
    assert (row.status, row.progress) == ("succeeded", 1) and "1 segments" in row.message
    assert scalar("SELECT count(*) FROM road_segments s JOIN networks n ON n.id = s.network_id"
                  " WHERE n.name = :n", n=name) == 1


def _queued_raster(folder: Path, slug: str, n: int) -> int:
    with session_scope() as session:
        return enqueue(session, "ingest-raster", {"sources": sources(folder, n), "layer": slug})


def test_fan_out_registers_the_layer_exactly_once(database_url: str, tmp_path: Path) -> None:
    """The tasks run here by hand, each twice (what a retried or duplicated delivery does):
    the layer is registered once, with every source, and the finish task queued once."""
    slug = f"fan-{uuid.uuid4().hex[:6]}"
    job_id = _queued_raster(tmp_path, slug, 3)
    tasks.run_job(job_id)
    tasks.run_job(job_id)  # a retry finds the parts already queued
    assert scalar("SELECT count(*) FROM procrastinate_jobs WHERE task_name = :t "
                  "AND (args->>'job_id')::bigint = :id", t=raster.WRITE_PART, id=job_id) == 3
    for part in (0, 1, 2, 2):
        tasks.raster_part(job_id, part)
    assert scalar("SELECT count(*) FROM procrastinate_jobs WHERE task_name = :t "
                  "AND (args->>'job_id')::bigint = :id", t=raster.FINISH, id=job_id) == 1
    assert scalar("SELECT count(*) FROM layers WHERE slug = :s", s=slug) == 0  # not yet
    tasks.raster_finish(job_id)
    tasks.raster_finish(job_id)
    assert layer_state(slug) == (1, 3)
    assert scalar("SELECT status FROM ingest_jobs WHERE id = :id", id=job_id) == "succeeded"
    assert set(open_store().refs_under(raster.job_prefix(slug, job_id))) == registered_uris(slug)


def test_a_bad_source_fails_the_queued_job_and_writes_nothing(database_url: str,
                                                              tmp_path: Path) -> None:
    slug = f"bad-{uuid.uuid4().hex[:6]}"
    good = sources(tmp_path, 1)[0]
    bogus = tmp_path / "bogus.tif"
    bogus.write_bytes(b"not a tiff")
    with session_scope() as session:
        job_id = enqueue(session, "ingest-raster", {"sources": [good, str(bogus)],
                                                    "layer": slug})
    with pytest.raises(Exception, match=r"bogus\.tif"):
        tasks.run_job(job_id)
    row = one("SELECT status, error FROM ingest_jobs WHERE id = :id", id=job_id)
    assert row.status == "failed" and "bogus.tif" in row.error
    assert scalar("SELECT count(*) FROM ingest_job_parts WHERE job_id = :id", id=job_id) == 0
    assert open_store().refs_under(raster.job_prefix(slug, job_id)) == []
    assert start_queued(job_id) is None  # a late delivery of the same job does nothing


def test_queue_schema_comes_and_goes_with_its_migration() -> None:
    def procrastinate_objects(conn) -> int:
        return conn.execute(text(
            "SELECT (SELECT count(*) FROM pg_class WHERE relname LIKE 'procrastinate%') + "
            "(SELECT count(*) FROM pg_proc WHERE proname LIKE 'procrastinate%') + "
            "(SELECT count(*) FROM pg_type WHERE typname LIKE '%procrastinate%')")).scalar()

    with scratch_database("ugvmap_queue_mig") as url:
        engine = create_engine(url)
        with engine.connect() as conn:
            assert procrastinate_objects(conn) > 20
        migrate.downgrade(url, "0002_network_change_notify")
        with engine.connect() as conn:
            assert procrastinate_objects(conn) == 0
            columns = {c["name"] for c in inspect(conn).get_columns("ingest_jobs")}
            assert "heartbeat_at" not in columns
        migrate.upgrade(url)
        with engine.connect() as conn:
            assert procrastinate_objects(conn) > 20
            assert migrate.current_revision(conn) == migrate.head_revision()
        engine.dispose()


@contextmanager
def worker_process(env: dict[str, str], log: Path) -> Iterator[subprocess.Popen]:
    with log.open("wb") as out:
        proc = subprocess.Popen([sys.executable, "-m", "cli", "worker", "--concurrency", "1"],
                                cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT)
        try:
            yield proc
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.wait(timeout=10)


@pytest.mark.slow
def test_queued_ingest_survives_a_worker_killed_mid_task(database_url: str,
                                                         tmp_path: Path) -> None:
    """Two `ugvmap worker` processes; one is SIGKILLed while it writes a source. Its task is
    retried on the other worker and the layer ends complete, registered once."""
    slug = f"kill-{uuid.uuid4().hex[:6]}"
    paths = sources(tmp_path, 4, size=1800)
    result = CliRunner().invoke(main, ["ingest", "raster", *paths, "--layer", slug, "--queue"])
    assert result.exit_code == 0, result.output
    job_id = int(result.output.split()[2])
    env = {**os.environ, "UGVMAP_JOB_LEASE_S": "3"}
    with worker_process(env, tmp_path / "a.log") as a, \
            worker_process(env, tmp_path / "b.log") as b:
        deadline = time.monotonic() + 60
        killed = None
        while killed is None and time.monotonic() < deadline:
            killed = scalar("SELECT part FROM ingest_job_parts WHERE job_id = :id AND "
                            "status = 'running' AND worker LIKE :w", id=job_id, w=f"%:{a.pid}")
            time.sleep(0.02)
        assert killed is not None, (tmp_path / "a.log").read_text()[-2000:]
        a.send_signal(signal.SIGKILL)
        a.wait(timeout=10)
        assert scalar("SELECT status FROM ingest_job_parts WHERE job_id = :id AND part = :p",
                      id=job_id, p=killed) == "running"  # killed mid-task, not after it
        deadline = time.monotonic() + 120
        while scalar("SELECT status FROM ingest_jobs WHERE id = :id", id=job_id) in (
                "queued", "running") and time.monotonic() < deadline:
            time.sleep(0.2)
        assert b.poll() is None
    log = (tmp_path / "b.log").read_text()
    assert scalar("SELECT status FROM ingest_jobs WHERE id = :id", id=job_id) == "succeeded", \
        log[-3000:]
    assert layer_state(slug) == (1, 4)
    part = one("SELECT attempts, worker FROM ingest_job_parts WHERE job_id = :id AND part = :p",
               id=job_id, p=killed)
    assert part.attempts == 2 and part.worker.endswith(f":{b.pid}")
    assert "its worker died; queued again" in log
    # the killed attempt's half-written file is gone; only the registered COGs remain
    assert set(open_store().refs_under(raster.job_prefix(slug, job_id))) == registered_uris(slug)
