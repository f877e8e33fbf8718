"""Record a job run in the calling process (``ugvmap ingest ...`` without ``--queue``).

The row is written on its own autocommit connection, not in the job's transaction (see
:mod:`app.jobs.rows`). While the job runs, a :class:`~app.jobs.lease.Lease` renews the row,
so a killed process's job is marked failed by :func:`~app.jobs.lease.reap_dead_jobs` instead
of staying ``running`` forever.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any

from app.db.session import get_engine
from app.jobs.lease import Lease, worker_name
from app.jobs.rows import failure_reason, record_failure, record_progress, record_success, write


class JobRecorder:
    """``with JobRecorder("raster", "my-layer", {...}) as job: job.progress(0.5, "tiles")``."""

    def __init__(self, kind: str, target: str | None,
                 params: dict[str, Any] | None = None) -> None:
        self.kind, self.target, self.params = kind, target, params or {}
        self.id: int | None = None
        self._lease: Lease | None = None

    def __enter__(self) -> JobRecorder:
        self.id = int(write(
            "INSERT INTO ingest_jobs (kind, target, params, status, started_at, heartbeat_at, "
            " worker) VALUES (:kind, :target, CAST(:params AS jsonb), 'running', now(), now(), "
            " :worker) RETURNING id",
            kind=self.kind, target=self.target, params=json.dumps(self.params, default=str),
            worker=worker_name()))
        self._lease = Lease(get_engine(), self.id)
        self._lease.__enter__()
        return self

    def progress(self, fraction: float, message: str | None = None) -> None:
        """Record progress (clamped to 0..1) and what the job is doing, visible at once on
        ``/jobs``."""
        assert self.id is not None
        record_progress(self.id, fraction, message)

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        assert self.id is not None and self._lease is not None
        self._lease.__exit__(exc_type, exc, tb)
        if exc is None:
            with get_engine().begin() as conn:
                record_success(conn, self.id)
        else:
            record_failure(self.id, failure_reason(exc))


class Throttle:
    """Forward progress to a job row at most every ``every_s`` seconds (and always at the end):
    a streamed import reports per chunk, and one UPDATE per chunk would be noise. ``report``:
    what records it (:meth:`JobRecorder.progress`, or a queued job's
    :func:`~app.jobs.rows.record_progress` for its id)."""

    def __init__(self, report: Callable[[float, str | None], None],
                 every_s: float = 1.0) -> None:
        self.report, self.every_s, self._last = report, every_s, -float("inf")

    def __call__(self, fraction: float, message: str | None = None) -> None:
        """Record ``fraction`` now if a second has passed (or the job is done), else drop it."""
        now = time.monotonic()
        if fraction >= 1.0 or now - self._last >= self.every_s:
            self._last = now
            self.report(fraction, message)
