"""``ugvmap worker``: run queued tasks, and take over the tasks of workers that died.

A worker is procrastinate's, with its heartbeat every third of ``UGVMAP_JOB_LEASE_S``. Next
to it, a watchdog (one worker at a time, under an advisory lock) asks procrastinate for the
tasks of workers whose heartbeat is older than a lease (SIGKILL, OOM, a lost machine) and
queues them again for any live worker, up to ``UGVMAP_JOB_MAX_ATTEMPTS`` runs; past that the
job is marked failed. It also marks failed the in-process ``ugvmap ingest`` jobs whose lease
ran out. Tasks are written to survive being run twice (:mod:`ingest.queue.raster`).
"""

from __future__ import annotations

import asyncio
import logging
import logging.config
from collections.abc import Iterator
from contextlib import contextmanager

import procrastinate
from procrastinate.jobs import Status
from sqlalchemy import text

from app.db.session import get_engine
from app.jobs.lease import reap_dead_jobs, worker_name
from app.jobs.queue import NAMESPACE, make_queue_app
from app.jobs.rows import record_failure
from app.logs import logging_config
from app.settings import get_settings
from ingest.queue import raster
from ingest.queue.tasks import blueprint

log = logging.getLogger(__name__)
WATCHDOG_LOCK = "ugvmap.queue.watchdog"


def make_worker_app(url: str | None = None) -> procrastinate.App:
    """A procrastinate app with every ugvmap task registered."""
    app = make_queue_app(url)
    app.add_tasks_from(blueprint, namespace=NAMESPACE)
    return app


@contextmanager
def _watchdog_lock() -> Iterator[bool]:
    """True when this worker holds the watchdog lock (others skip their turn)."""
    with get_engine().connect() as conn:
        key = {"key": WATCHDOG_LOCK}
        held = bool(conn.execute(text("SELECT pg_try_advisory_lock(hashtext(:key))"),
                                 key).scalar())
        try:
            yield held
        finally:
            if held:
                conn.execute(text("SELECT pg_advisory_unlock(hashtext(:key))"), key)
            conn.commit()


async def recover_stalled(app: procrastinate.App) -> list[int]:
    """Queue again the tasks of dead workers (or fail their jobs past the attempt limit);
    returns the procrastinate ids of the tasks queued again."""
    settings = get_settings()
    retried: list[int] = []
    with _watchdog_lock() as held:
        if not held:
            return retried
        for task in await app.job_manager.get_stalled_jobs(
                seconds_since_heartbeat=settings.job_lease_s):
            assert task.id is not None
            if task.attempts + 1 < settings.job_max_attempts:
                log.warning("task %s %s: its worker died; queued again", task.id,
                            task.call_string)
                await app.job_manager.retry_job(task)
                retried.append(task.id)
                continue
            log.error("task %s %s: its worker died %d times; giving up", task.id,
                      task.call_string, settings.job_max_attempts)
            await app.job_manager.finish_job(task, status=Status.FAILED, delete_job=False)
            job_id = task.task_kwargs.get("job_id")
            if isinstance(job_id, int):
                await asyncio.to_thread(
                    record_failure, job_id, f"the worker running {task.task_name} died "
                    f"{settings.job_max_attempts} times")
                await asyncio.to_thread(raster.discard, job_id)
    return retried


def _reap() -> None:
    with get_engine().begin() as conn:
        reap_dead_jobs(conn)


async def _watch(app: procrastinate.App) -> None:
    while True:
        try:
            await recover_stalled(app)
            await asyncio.to_thread(_reap)
        except Exception:  # the database may be away for a while: try again next round
            log.exception("watchdog round failed")
        await asyncio.sleep(get_settings().job_lease_s / 3)


async def serve(concurrency: int, url: str | None = None) -> None:
    """Run tasks, ``concurrency`` at a time, until SIGINT/SIGTERM (running tasks finish)."""
    lease = get_settings().job_lease_s
    app = make_worker_app(url)
    async with app.open_async():
        watchdog = asyncio.create_task(_watch(app))
        try:
            await app.run_worker_async(
                name=worker_name(), concurrency=concurrency, delete_jobs="successful",
                update_heartbeat_interval=lease / 3, stalled_worker_timeout=lease)
        finally:
            watchdog.cancel()


def run_worker(concurrency: int) -> None:
    """The ``ugvmap worker`` command's body: JSON log lines, then :func:`serve`."""
    logging.config.dictConfig(logging_config(get_settings().log_level))
    asyncio.run(serve(concurrency))
