"""The queue's tasks, on a procrastinate blueprint that ``ugvmap worker`` registers under the
``ugvmap`` namespace (names in :mod:`app.jobs.queue` and :mod:`ingest.queue.raster`).

Every task takes the ``ingest_jobs`` id and reads the rest from the row, so the queue's
arguments stay small and the row stays the one record of a job. A task that raises marks its
job failed (the queue does not retry errors: a bad input fails the same way twice); a task
whose worker died is retried by the worker loop (:mod:`ingest.queue.worker`).
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Callable, Iterator
from typing import Any, cast

import procrastinate

from app.jobs.kinds import JOB_KINDS
from app.jobs.rows import JobEndedError, failure_reason, record_failure, start_queued
from ingest.queue import raster

blueprint = procrastinate.Blueprint()


@contextlib.contextmanager
def failing_job(job_id: int, cleanup: Callable[[int], None] | None = None) -> Iterator[None]:
    """Mark the job failed (and ``cleanup`` its files) if the block raises; a run that found
    its job already ended just stops."""
    try:
        yield
    except JobEndedError:
        return
    except Exception as exc:
        record_failure(job_id, failure_reason(exc))
        if cleanup is not None:
            cleanup(job_id)
        raise


def resolve_runner(name: str) -> Callable[[int, Any], None]:
    """The function a ``module:function`` runner name (:data:`~app.jobs.kinds.JOB_KINDS`)
    names; a typo raises here (and in the test that resolves every name), not in a worker."""
    module, _, function = name.partition(":")
    runner = getattr(importlib.import_module(module), function)
    if not callable(runner):
        raise TypeError(f"runner {name} is not a function")
    return cast("Callable[[int, Any], None]", runner)


@blueprint.task(name="run_job")
def run_job(job_id: int) -> None:
    """A job's first task: the runner its kind names in :data:`~app.jobs.kinds.JOB_KINDS`."""
    row = start_queued(job_id)
    if row is None:
        return
    kind = JOB_KINDS[row.kind]
    with failing_job(job_id):
        resolve_runner(kind.runner)(job_id, kind.params.model_validate(row.params))


@blueprint.task(name="raster_part")
def raster_part(job_id: int, part: int) -> None:
    """Write one source of a raster job."""
    with failing_job(job_id, raster.discard):
        raster.write_part(job_id, part)


@blueprint.task(name="raster_finish")
def raster_finish(job_id: int) -> None:
    """Register a raster job's layer once every source is written."""
    with failing_job(job_id, raster.discard):
        raster.finish(job_id)
