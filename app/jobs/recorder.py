"""Record a batch job's status and progress in ``ingest_jobs``.

The row is written on its own autocommit connection, not in the job's transaction: an ingest
commits its catalogue rows only at the very end (so a failed job leaves nothing half
registered), yet the API and other users must see "running, 40 %" while it works, and see
"failed: <reason>" after a crash that rolled the job's own transaction back.
"""

from __future__ import annotations

import json
import time
import traceback
from types import TracebackType
from typing import Any

from sqlalchemy import text

from app.db.session import get_engine

MAX_ERROR = 2000


class JobRecorder:
    """``with JobRecorder("raster", "my-layer", {...}) as job: job.progress(0.5, "tiles")``."""

    def __init__(self, kind: str, target: str | None,
                 params: dict[str, Any] | None = None) -> None:
        self.kind, self.target, self.params = kind, target, params or {}
        self.engine = get_engine()
        self.id: int | None = None

    def _write(self, sql: str, **values: Any) -> Any:
        with self.engine.connect().execution_options(isolation_level="AUTOCOMMIT") as conn:
            result = conn.execute(text(sql), {"id": self.id, **values})
            return result.scalar() if result.returns_rows else None

    def __enter__(self) -> JobRecorder:
        self.id = self._write(
            "INSERT INTO ingest_jobs (kind, target, params, status, started_at) "
            "VALUES (:kind, :target, CAST(:params AS jsonb), 'running', now()) RETURNING id",
            kind=self.kind, target=self.target, params=json.dumps(self.params, default=str))
        return self

    def progress(self, fraction: float, message: str | None = None) -> None:
        """Record progress (clamped to 0..1) and what the job is doing, visible at once on
        ``/jobs``."""
        self._write("UPDATE ingest_jobs SET progress = :p, message = :m WHERE id = :id",
                    p=min(1.0, max(0.0, fraction)), m=message)

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc is None:
            self._write("UPDATE ingest_jobs SET status = 'succeeded', progress = 1, "
                        "finished_at = now() WHERE id = :id")
            return
        reason = str(exc) or "".join(traceback.format_exception_only(exc)).strip()
        if isinstance(exc, KeyboardInterrupt):
            reason = "interrupted"
        self._write("UPDATE ingest_jobs SET status = 'failed', error = :e, finished_at = now() "
                    "WHERE id = :id", e=reason[:MAX_ERROR])


class Throttle:
    """Forward progress to a job row at most every ``every_s`` seconds (and always at the end):
    a streamed import reports per chunk, and one UPDATE per chunk would be noise."""

    def __init__(self, job: JobRecorder, every_s: float = 1.0) -> None:
        self.job, self.every_s, self._last = job, every_s, -float("inf")

    def __call__(self, fraction: float, message: str | None = None) -> None:
        """Record ``fraction`` now if a second has passed (or the job is done), else drop it."""
        now = time.monotonic()
        if fraction >= 1.0 or now - self._last >= self.every_s:
            self._last = now
            self.job.progress(fraction, message)
