"""Throwaway databases on the configured server, for the test suite and the benchmarks.

One place that knows how to make (and always drop) a database with PostGIS + pgRouting,
migrated to head or left empty, so tests and benchmarks never touch a user's data.
"""

from __future__ import annotations

import os
import tempfile
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import psycopg
from sqlalchemy.engine import make_url

from app.db import migrate
from app.db.session import get_engine, libpq_dsn
from app.settings import get_settings
from cli.ops import embedded


@contextmanager
def scratch_database(prefix: str = "ugvmap_scratch", *, migrated: bool = True,
                     base_url: str | None = None) -> Iterator[str]:
    """Yield the URL of a new database on ``base_url``'s server (default: the configured
    one, starting the embedded cluster if that is it), dropped on exit."""
    settings = get_settings()
    if base_url is None and settings.embedded:
        embedded.start(embedded.cluster_from(settings))
    base = make_url(base_url or settings.database_url)
    name = f"{prefix}_{uuid.uuid4().hex[:10]}"
    admin = libpq_dsn(base.set(database="postgres").render_as_string(hide_password=False))
    url = base.set(database=name).render_as_string(hide_password=False)
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        if migrated:
            embedded.ensure_database(admin, name)
            migrate.upgrade(url)
        yield url
    finally:
        get_engine(url).dispose()
        with psycopg.connect(admin, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@contextmanager
def bench_database(prefix: str) -> Iterator[tuple[str, Path, dict[str, str]]]:
    """A scratch database and a raster store in a temporary folder that this process uses
    until the block ends (a benchmark's whole run): (its URL, the folder, the environment a
    server started on them needs)."""
    with scratch_database(prefix) as url, \
            tempfile.TemporaryDirectory(prefix=f"{prefix}-") as tmp:
        env = {"DATABASE_URL": url, "UGVMAP_RASTER_STORE": f"{tmp}/rasters"}
        os.environ.update(env)
        get_settings.cache_clear()
        get_engine.cache_clear()
        yield url, Path(tmp), {**env, "UGVMAP_LOG_LEVEL": "WARNING"}
