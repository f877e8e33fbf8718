"""Leases on ``ingest_jobs`` rows: how a dead job is told apart from a slow one.

A process working on a job renews the row's ``heartbeat_at`` every third of
``UGVMAP_JOB_LEASE_S`` from a daemon thread, on its own connection (the job's transaction may
stay open for minutes). A SIGKILL, an OOM kill or a lost machine stops the renewals, so a
``running`` row whose lease ran out belongs to a dead process: :func:`reap_dead_jobs` marks it
failed. Queued jobs are not reaped here: the queue retries their tasks on another worker
(``ugvmap worker``), and only the queue decides when such a job has failed for good.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
from types import TracebackType

from sqlalchemy import Connection, Engine, text
from sqlalchemy.exc import SQLAlchemyError

from app.settings import get_settings

log = logging.getLogger(__name__)


def worker_name() -> str:
    """``host:pid`` of this process, recorded on the rows it works on (shown to admins)."""
    return f"{socket.gethostname()}:{os.getpid()}"


class Lease:
    """``with Lease(engine, job_id): ...`` keeps renewing the job row's lease while the block
    runs; the renewals stop with the block, or with the process."""

    def __init__(self, engine: Engine, job_id: int) -> None:
        self.engine, self.job_id = engine, job_id
        self.every_s = get_settings().job_lease_s / 3
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"lease-{job_id}", daemon=True)

    def renew(self) -> None:
        """Push the lease's end forward now (and say which process holds it)."""
        with self.engine.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
            conn.execute(text("UPDATE ingest_jobs SET heartbeat_at = now(), worker = :w "
                              "WHERE id = :id"), {"id": self.job_id, "w": worker_name()})

    def _run(self) -> None:
        while not self._stop.wait(self.every_s):
            try:
                self.renew()
            except SQLAlchemyError as exc:  # a database blip must not kill the job itself
                log.warning("job %s: lease not renewed (%s)", self.job_id, exc)

    def __enter__(self) -> Lease:
        self.renew()
        self._thread.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stop.set()
        self._thread.join()


def reap_dead_jobs(conn: Connection) -> int:
    """Mark failed every in-process job whose lease ran out; returns how many.

    Called wherever jobs are listed (``GET /jobs``, ``ugvmap jobs``) and by workers, so a
    killed ``ugvmap ingest`` never shows ``running`` for longer than one lease.
    """
    result = conn.execute(text(
        "UPDATE ingest_jobs SET status = 'failed', finished_at = now(), "
        " error = 'the process running the job died (' || COALESCE(worker, 'unknown') || "
        "   ' stopped renewing its lease at ' || "
        "   to_char(COALESCE(heartbeat_at, started_at, created_at), 'YYYY-MM-DD HH24:MI:SS TZ')"
        "   || ')' "
        "WHERE status = 'running' AND NOT queued "
        "  AND COALESCE(heartbeat_at, started_at, created_at) "
        "      < now() - make_interval(secs => :lease)"),
        {"lease": get_settings().job_lease_s})
    return result.rowcount
