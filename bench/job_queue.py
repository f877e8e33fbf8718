"""Benchmark: a multi-source raster ingest in the calling process vs queued to workers.

Baseline: ``ugvmap ingest raster SRC... --layer a`` (sources written one after another in one
process). Queued: ``ugvmap ingest raster SRC... --layer b --queue`` with ``--workers`` worker
processes already running (one task per source, then one registration), timed from the
``--queue`` command to the job row's ``succeeded``. Same sources, same database, same run.
Also prints the queue's own cost: a queued job of one tiny source, end to end.

Run: ``.venv/bin/python bench/job_queue.py [--sources 6] [--size 2000] [--workers 2]`` (uses
DATABASE_URL or the embedded cluster; creates and drops a throwaway database and store).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from sqlalchemy import create_engine, text

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from testkit.raster_synth import synthetic_utm, utm_origin  # noqa: E402
from testkit.scratch import scratch_database  # noqa: E402


def ugvmap(env: dict[str, str], *args: str) -> str:
    """Run one ``ugvmap`` command; its output."""
    return subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, env=env, check=True,
                          capture_output=True, text=True).stdout


def wait_for(url: str, job_id: int, timeout_s: float = 1800) -> float:
    """Seconds until job ``job_id`` succeeded (raises if it failed or timed out)."""
    engine = create_engine(url.replace("postgresql://", "postgresql+psycopg://", 1))
    start = time.perf_counter()
    with engine.connect() as conn:
        while time.perf_counter() - start < timeout_s:
            status, error = conn.execute(text("SELECT status, error FROM ingest_jobs "
                                              "WHERE id = :id"), {"id": job_id}).one()
            conn.rollback()
            if status == "succeeded":
                return time.perf_counter() - start
            if status == "failed":
                raise RuntimeError(f"job {job_id} failed: {error}")
            time.sleep(0.05)
    raise TimeoutError(f"job {job_id} did not finish")


def wait_for_workers(url: str, count: int, timeout_s: float = 120) -> None:
    """Until ``count`` workers have registered (imports done, listening for tasks)."""
    engine = create_engine(url.replace("postgresql://", "postgresql+psycopg://", 1))
    deadline = time.monotonic() + timeout_s
    with engine.connect() as conn:
        while conn.execute(text("SELECT count(*) FROM procrastinate_workers")).scalar() < count:
            conn.rollback()
            if time.monotonic() > deadline:
                raise TimeoutError("the workers did not start")
            time.sleep(0.1)


def queued(env: dict[str, str], url: str, *args: str) -> float:
    """Queue an ingest and time it to success."""
    start = time.perf_counter()
    job_id = int(ugvmap(env, "ingest", "raster", *args, "--queue").split()[2])
    wait_for(url, job_id)
    return time.perf_counter() - start


def main() -> None:
    """Make the sources, start the workers, time both ways, print the ratio."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sources", type=int, default=6)
    parser.add_argument("--size", type=int, default=2000, help="pixels per side per source")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp, scratch_database("ugvmap_bench_queue") as url:
        folder = Path(tmp)
        east, north = utm_origin()
        paths = [str(synthetic_utm(folder / f"zone{i}.tif", args.size, args.size, 0.3,
                                   (east + i * args.size * 0.3, north))[0])
                 for i in range(args.sources)]
        tiny = str(synthetic_utm(folder / "tiny.tif", 256, 256, 0.3)[0])
        env = {**os.environ, "DATABASE_URL": url, "UGVMAP_RASTER_STORE": str(folder / "store")}
        start = time.perf_counter()
        ugvmap(env, "ingest", "raster", *paths, "--layer", "inline")
        inline_s = time.perf_counter() - start
        workers = [subprocess.Popen([sys.executable, "-m", "cli", "worker"], cwd=REPO, env=env,
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                   for _ in range(args.workers)]
        try:
            wait_for_workers(url, args.workers)
            overhead_s = queued(env, url, tiny, "--layer", "tiny")
            inline_tiny_start = time.perf_counter()
            ugvmap(env, "ingest", "raster", tiny, "--layer", "tiny-inline")
            inline_tiny_s = time.perf_counter() - inline_tiny_start
            queued_s = queued(env, url, *paths, "--layer", "fanned")
        finally:
            for worker in workers:
                worker.terminate()
            for worker in workers:
                worker.wait(timeout=60)
    print(f"{args.sources} sources of {args.size}x{args.size} px, {args.workers} workers "
          f"(1 task each), {os.cpu_count()} cores")
    print(f"{'run':<34}{'seconds':>9}")
    print(f"{'in the calling process':<34}{inline_s:>9.2f}")
    print(f"{'queued, fanned out':<34}{queued_s:>9.2f}")
    print(f"{'ratio queued / in-process':<34}{queued_s / inline_s:>9.2f}")
    print(f"{'one tiny source, queued':<34}{overhead_s:>9.2f}")
    print(f"{'one tiny source, in-process':<34}{inline_tiny_s:>9.2f}")


if __name__ == "__main__":
    main()
