"""Every read and status change of an ``ingest_jobs`` row, for in-process and queued jobs alike.

Progress and failures are written on their own autocommit connection, never in the job's
transaction: an ingest commits its catalogue rows only at the very end, yet ``/jobs`` must
show "running, 40 %" while it works and "failed: <reason>" after its transaction rolled back.
Success is the exception: a queued job records it *in* the transaction that commits its
work (:func:`succeed_in`), so a task retried after a crash can tell it already happened.
"""

from __future__ import annotations

import traceback
from typing import Any

from sqlalchemy import Connection, text

from app.db.session import get_engine
from app.jobs.lease import reap_dead_jobs, worker_name

MAX_ERROR = 2000
COLUMNS = (
    "j.id, j.kind, j.target, j.params, j.status, j.progress, j.message, j.error, j.created_at, "
    "j.started_at, j.finished_at, j.heartbeat_at, j.queued, j.worker, "
    "(SELECT json_object_agg(status, n) FROM (SELECT status, count(*) AS n "
    "  FROM ingest_job_parts p WHERE p.job_id = j.id GROUP BY status) s) AS parts")


def write(sql: str, **values: Any) -> Any:
    """Run ``sql`` on its own autocommit connection; the first column of its row, if any."""
    with get_engine().connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
        result = conn.execute(text(sql), values)
        return result.scalar() if result.returns_rows else None


def record_progress(job_id: int, fraction: float, message: str | None = None) -> None:
    """Progress (clamped to 0..1) and what the job is doing, visible at once on ``/jobs``."""
    write("UPDATE ingest_jobs SET progress = :p, message = :m WHERE id = :id",
          id=job_id, p=min(1.0, max(0.0, fraction)), m=message)


def failure_reason(exc: BaseException) -> str:
    """The one line a failed job shows: the exception's message, or its type."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted"
    return (str(exc) or "".join(traceback.format_exception_only(exc)).strip())[:MAX_ERROR]


def record_failure(job_id: int, reason: str) -> None:
    """Mark a job failed, unless it already ended (a late duplicate must not undo a success)."""
    write("UPDATE ingest_jobs SET status = 'failed', error = :e, finished_at = now() "
          "WHERE id = :id AND status IN ('queued', 'running')", id=job_id, e=reason[:MAX_ERROR])


def record_success(conn: Connection, job_id: int, message: str | None = None) -> None:
    """Mark a job succeeded on ``conn`` (the job's own transaction, or autocommit)."""
    conn.execute(text("UPDATE ingest_jobs SET status = 'succeeded', progress = 1, "
                      "message = COALESCE(:m, message), finished_at = now() WHERE id = :id"),
                 {"id": job_id, "m": message})


def lock_running(conn: Connection, job_id: int) -> bool:
    """Lock a queued job's row; False when it is no longer running (another run of the same
    task finished it first, or it failed). Take it last in a transaction: the lock holds back
    the job's own progress and lease writes until the commit."""
    status = conn.execute(text("SELECT status FROM ingest_jobs WHERE id = :id FOR UPDATE"),
                          {"id": job_id}).scalar()
    return status == "running"


class JobEndedError(Exception):
    """The job is no longer running: this run's work must be rolled back, not committed."""


def succeed_in(conn: Connection, job_id: int, message: str | None = None) -> None:
    """Mark a queued job succeeded in the transaction that commits its work, so the work
    lands exactly once: raises :class:`JobEndedError` if another run got there first."""
    if not lock_running(conn, job_id):
        raise JobEndedError(f"job {job_id} already ended")
    record_success(conn, job_id, message)


def start_queued(job_id: int) -> Any:
    """A worker takes a queued job: ``running``, with this worker's lease; its ``kind`` and
    ``params``, or None when the job already ended (a duplicate or late delivery)."""
    with get_engine().begin() as conn:
        return conn.execute(text(
            "UPDATE ingest_jobs SET status = 'running', started_at = COALESCE(started_at, now()),"
            " heartbeat_at = now(), worker = :w "
            "WHERE id = :id AND status IN ('queued', 'running') RETURNING kind, params"),
            {"id": job_id, "w": worker_name()}).first()


def read_jobs(conn: Connection, *, job_id: int | None = None, status: str | None = None,
              limit: int = 50) -> list[Any]:
    """Job rows, newest first (one, with ``job_id``); jobs whose process died are marked
    failed first, so no reader ever sees a dead job ``running``."""
    reap_dead_jobs(conn)
    return list(conn.execute(text(
        f"SELECT {COLUMNS} FROM ingest_jobs j "
        "WHERE (CAST(:id AS bigint) IS NULL OR j.id = :id) "
        "  AND (CAST(:s AS text) IS NULL OR j.status = :s) ORDER BY j.id DESC LIMIT :limit"),
        {"id": job_id, "s": status, "limit": limit}))
