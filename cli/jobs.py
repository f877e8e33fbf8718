"""``ugvmap jobs`` (what the batch jobs do or did), ``ugvmap worker`` (run queued jobs) and the
``--queue`` path of every ``ugvmap ingest`` command.

Registered in :mod:`cli.main`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from app.db.models import JOB_STATUSES

queue_option = click.option(
    "--queue", "queued", is_flag=True,
    help="Queue the job for `ugvmap worker` (on any machine reaching the same database and "
         "raster store) instead of running it here; prints the job id.")


def enqueue_job(kind: str, params: dict[str, Any]) -> None:
    """Queue a job of ``kind`` (parameters checked first) and say how to follow it."""
    from app.db.session import session_scope
    from app.jobs.queue import enqueue

    with session_scope() as session:
        job_id = enqueue(session, kind, params)
    click.echo(f"queued job {job_id} ({kind}); `ugvmap worker` runs it, "
               f"`ugvmap jobs` follows it")


def absolute(path: Path | None) -> str | None:
    """A path as workers see it: absolute (their working directory is not ours)."""
    return None if path is None else str(path.resolve())


@click.command("jobs")
@click.option("--status", type=click.Choice(JOB_STATUSES), help="Only jobs in this state.")
@click.option("--limit", type=click.IntRange(1, 500), default=20, show_default=True)
def jobs(status: str | None, limit: int) -> None:
    """Recent jobs, newest first: id, kind, target, status, progress, where it ran, and its
    message or error (jobs whose process died are marked failed first)."""
    from app.db.session import session_scope
    from app.jobs.rows import read_jobs

    with session_scope() as session:
        rows = read_jobs(session.connection(), status=status, limit=limit)
    for r in rows:
        where = "queue" if r.queued else "local"
        parts = ",".join(f"{k}:{v}" for k, v in sorted((r.parts or {}).items()))
        click.echo(f"{r.id}\t{r.kind}\t{r.target}\t{r.status}\t{r.progress:4.0%}\t{where}"
                   f"\t{r.created_at:%Y-%m-%d %H:%M:%S}\t{r.error or r.message or ''}"
                   + (f"\tparts {parts}" if parts else ""))


@click.command("worker")
@click.option("--concurrency", type=click.IntRange(1, 64), default=1, show_default=True,
              help="Tasks run at the same time in this process.")
def worker(concurrency: int) -> None:
    """Run queued jobs until stopped (Ctrl-C / SIGTERM lets running tasks finish). Start one
    on every machine that reaches the database and the raster store."""
    from ingest.queue.worker import run_worker

    run_worker(concurrency)
