"""The job queue: procrastinate, on the PostgreSQL database ugvmap already has.

Why procrastinate: the queue lives in tables of our own database (migration ``0005_queue``),
so there is no broker to run, back up or secure, a job is queued in the same transaction as
its ``ingest_jobs`` row (never one without the other), workers wake on LISTEN/NOTIFY, and a
worker killed mid-task is found through its heartbeat and its task retried elsewhere.

Deferring always goes through the caller's own connection (:func:`defer`), so this module's
app is never opened: no pool, nothing to close. ``ugvmap worker`` builds its own app with the
tasks (``ingest.queue.tasks``) and opens that one.
"""

from __future__ import annotations

import json
from functools import lru_cache
from typing import TYPE_CHECKING, Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.db.session import libpq_dsn
from app.jobs.kinds import validate_job
from app.settings import get_settings

if TYPE_CHECKING:
    import procrastinate

#: The tasks' namespace (``procrastinate.App.add_tasks_from``) and the entry task of a job.
NAMESPACE = "ugvmap"
RUN_JOB = f"{NAMESPACE}:run_job"


def make_queue_app(url: str | None = None, **pool: Any) -> procrastinate.App:
    """A procrastinate app on ``url`` (default: the configured database); imported here, not
    at module level, so the HTTP service loads it only when a job is queued."""
    import procrastinate

    dsn = libpq_dsn(url or get_settings().database_url)
    return procrastinate.App(connector=procrastinate.PsycopgConnector(conninfo=dsn, **pool))


@lru_cache(maxsize=4)
def _deferring_app(url: str) -> procrastinate.App:
    return make_queue_app(url)


def defer(session: Session, task: str, **kwargs: Any) -> int:
    """Queue ``task(**kwargs)`` in the session's transaction: it is queued when the caller
    commits, and never if the caller rolls back."""
    connection = session.connection().connection.driver_connection
    app = _deferring_app(get_settings().database_url)
    return app.configure_task(task, connection=connection).defer(**kwargs)


def enqueue(session: Session, kind: Any, params: Any) -> int:
    """Validate a job, insert its ``queued`` row and queue its first task, in the caller's
    transaction; returns the job id. Bad parameters raise 422 ``InvalidValue`` before
    anything is written."""
    job = validate_job(kind, params)
    job_id: int = session.execute(text(
        "INSERT INTO ingest_jobs (kind, target, params, status, queued) "
        "VALUES (:kind, :target, CAST(:params AS jsonb), 'queued', true) RETURNING id"),
        {"kind": kind, "target": job.target,
         "params": json.dumps(job.model_dump(mode="json"))}).scalar_one()
    defer(session, RUN_JOB, job_id=job_id)
    return job_id
