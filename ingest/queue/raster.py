"""A queued raster ingest: one task per source, then the layer registered once, atomically.

1. :func:`run` validates every source (nothing is written if one is bad), then, in one
   transaction, inserts one ``ingest_job_parts`` row per source and queues one
   :func:`write_part` task per part (a retry of ``run`` finds the parts and stops).
2. Each :func:`write_part` writes its COG into the job's own folder of the store
   (``<store>/<layer>/job-<id>/``, where another ingest's leftover sweep never looks) and, in
   one transaction holding the job row's lock, marks its part done; the part that finds no
   part left queues :func:`finish` in that same transaction, so exactly one does, once.
3. :func:`finish` registers every part's COG through :func:`ingest.raster.job.register`
   (layer upsert, sources, overview, ``version + 1``) and marks the job succeeded in the same
   transaction: a run killed before its commit left nothing, and a run after a commit finds
   the job succeeded and does nothing. The layer is never half-registered.

A worker killed mid-part leaves the part ``running``; the queue retries its task on another
worker (``ugvmap worker``: procrastinate's heartbeat), which writes the COG again. Files of
killed attempts are deleted by ``finish``; a failed job deletes the COGs of its parts.
"""

from __future__ import annotations

import base64
import contextlib
import json
import uuid
from collections.abc import Callable, Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any

from sqlalchemy import text

from app.db.session import get_engine, session_scope
from app.jobs.kinds import RasterParams
from app.jobs.lease import Lease, worker_name
from app.jobs.queue import NAMESPACE, defer
from app.jobs.rows import lock_running, record_progress, succeed_in
from app.tiles.store import RasterStore, claim_root, open_store, remove_files
from ingest.raster.gcps import gcp_writer, inspect_with_gcps, read_gcps
from ingest.raster.job import (
    IngestReport,
    WrittenSource,
    checksum,
    layer_lock,
    refuse_duplicates,
    refuse_far,
    register,
    sweep_leftovers,
    write_source,
)
from ingest.raster.sources import Source, inspect

WRITE_PART = f"{NAMESPACE}:raster_part"
FINISH = f"{NAMESPACE}:raster_finish"


def _reader(params: RasterParams) -> tuple[Callable[[Path], Source],
                                           Callable[[Source, Path], None] | None]:
    """How to validate each source, and how to write it (GCP warp, or the plain COG copy)."""
    if params.gcps is not None:
        gcps = read_gcps(Path(params.gcps), params.crs)
        return (lambda p: inspect_with_gcps(p, gcps)), gcp_writer(params.gcp_method)
    return (lambda p: inspect(p, crs=params.crs)), None


def job_prefix(layer: str, job_id: int) -> str:
    """The store folder (key prefix) the job's COGs are written to, and stay in once
    registered."""
    return f"{layer}/job-{job_id}"


def _to_json(written: WrittenSource) -> dict[str, Any]:
    data = asdict(written)
    data["footprint_wkb"] = base64.b64encode(written.footprint_wkb).decode()
    return data


def _from_json(data: dict[str, Any]) -> WrittenSource:
    return WrittenSource(**{**data, "footprint_wkb": base64.b64decode(data["footprint_wkb"])})


def run(job_id: int, params: RasterParams) -> None:
    """Validate every source, then queue one :func:`write_part` task per source."""
    check, _ = _reader(params)
    checked = [check(Path(path)) for path in params.sources]
    names, bounds = [c.name for c in checked], [c.bounds_4326 for c in checked]
    with get_engine().connect() as conn:
        if not params.replace:
            refuse_duplicates(conn, params.layer, names,
                              [checksum(Path(p)) for p in params.sources])
        if not params.add:
            refuse_far(conn, params.layer, names, bounds)
    with session_scope() as session:
        if not lock_running(session.connection(), job_id):
            return
        if session.execute(text("SELECT count(*) FROM ingest_job_parts WHERE job_id = :id"),
                           {"id": job_id}).scalar_one():
            return  # a retry: the parts were queued by the run that committed them
        for part, path in enumerate(params.sources):
            session.execute(text("INSERT INTO ingest_job_parts (job_id, part, source) "
                                 "VALUES (:id, :part, :source)"),
                            {"id": job_id, "part": part, "source": path})
            defer(session, WRITE_PART, job_id=job_id, part=part)
        session.execute(text("UPDATE ingest_jobs SET message = :m WHERE id = :id"),
                        {"id": job_id, "m": f"{len(params.sources)} sources queued"})


def write_part(job_id: int, part: int) -> None:
    """Write one source's COG, then mark its part done (and queue :func:`finish` if last)."""
    with get_engine().begin() as conn:
        row = conn.execute(text(
            "UPDATE ingest_job_parts p SET status = 'running', attempts = attempts + 1, "
            " worker = :w, updated_at = now() FROM ingest_jobs j "
            "WHERE j.id = p.job_id AND j.status = 'running' AND p.job_id = :id "
            "  AND p.part = :part AND p.status <> 'succeeded' RETURNING p.source, j.params"),
            {"id": job_id, "part": part, "w": worker_name()}).first()
    if row is None:
        return  # the part is done (a duplicate delivery) or the job ended
    source, params = row.source, RasterParams.model_validate(row.params)
    check, to_cog = _reader(params)
    store, prefix = open_store(), job_prefix(params.layer, job_id)
    with Lease(get_engine(), job_id), store.staging(prefix) as staging:
        try:
            with get_engine().begin() as conn:  # a worker with another store writes nothing
                claim_root(conn)
            written = write_source(check(Path(source)), store, staging, prefix, to_cog)
        except BaseException:
            with get_engine().begin() as conn:
                conn.execute(text("UPDATE ingest_job_parts SET status = 'failed', "
                                  "updated_at = now() WHERE job_id = :id AND part = :part"),
                             {"id": job_id, "part": part})
            raise
    with _discard_unless_kept(store, written.uri) as keep, session_scope() as session:
        if not lock_running(session.connection(), job_id):
            return  # the job failed meanwhile: this COG will never be registered
        marked = session.connection().execute(text(
            "UPDATE ingest_job_parts SET status = 'succeeded', result = CAST(:r AS jsonb), "
            " updated_at = now() WHERE job_id = :id AND part = :part AND status <> 'succeeded'"),
            {"id": job_id, "part": part, "r": json.dumps(_to_json(written))}).rowcount
        if not marked:
            return  # a duplicate run of this part finished first
        keep()
        done, total = (int(n) for n in session.execute(text(
            "SELECT count(*) FILTER (WHERE status = 'succeeded'), count(*) "
            "FROM ingest_job_parts WHERE job_id = :id"), {"id": job_id}).one())
        session.execute(text("UPDATE ingest_jobs SET progress = :p, message = :m WHERE id = :id"),
                        {"id": job_id, "p": done / (total + 1),
                         "m": f"{done}/{total} sources written"})
        if done == total:
            defer(session, FINISH, job_id=job_id)


@contextlib.contextmanager
def _discard_unless_kept(store: RasterStore, uri: str) -> Iterator[Callable[[], None]]:
    """Delete the object ``uri`` when the block ends, unless ``keep()`` was called in it and the
    block's transaction committed (a rolled-back mark keeps nothing)."""
    kept = []
    try:
        yield lambda: kept.append(True)
    except BaseException:
        kept.clear()
        raise
    finally:
        if not kept:
            store.delete([uri])


def finish(job_id: int) -> None:
    """Register every part's COG in one transaction with the job's success."""
    with get_engine().connect() as conn:
        row = conn.execute(text("SELECT status, params FROM ingest_jobs WHERE id = :id"),
                           {"id": job_id}).one()
    if row.status != "running":
        return
    params = RasterParams.model_validate(row.params)
    store = open_store()
    record_progress(job_id, 0.99, "registering the layer")
    with Lease(get_engine(), job_id), layer_lock(params.layer), \
            store.staging(params.layer) as staging:
        sweep_leftovers(store, params.layer)
        overview = staging / f"overview-{uuid.uuid4().hex}.tif"
        try:
            with session_scope() as session:
                written = [_from_json(r) for r in session.scalars(text(
                    "SELECT result FROM ingest_job_parts WHERE job_id = :id ORDER BY part"),
                    {"id": job_id})]
                done = register(session, written, params.layer, params.title, params.kind,
                                params.priority, overview, store, params.replace, params.add)
                # The rest of the job's folder (files of killed attempts) goes before the job
                # is said to have succeeded: whoever sees it done finds only registered COGs.
                kept = {w.uri for w in written}
                store.delete([r for r in store.refs_under(job_prefix(params.layer, job_id))
                              if r not in kept])
                report = IngestReport(params.layer, done.shape.version, written, done.shape,
                                      done.replaced_sources)
                succeed_in(session.connection(), job_id, report.summary())
        except BaseException:
            overview.unlink(missing_ok=True)
            with contextlib.suppress(Exception):  # the original error matters more
                store.delete([store.ref(f"{params.layer}/{overview.name}")])
            raise
    if done.replaced:
        remove_files(get_engine(), done.replaced, store)


def discard(job_id: int) -> None:
    """A failed job's COGs: delete those its parts wrote (none of them is registered)."""
    with get_engine().connect() as conn:
        uris: list[str] = list(conn.execute(text(
            "SELECT p.result->>'uri' FROM ingest_job_parts p JOIN ingest_jobs j ON j.id = p.job_id"
            " WHERE p.job_id = :id AND j.status = 'failed' AND p.result IS NOT NULL"),
            {"id": job_id}).scalars())
    open_store().delete(uris)
