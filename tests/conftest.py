"""Test fixtures: a throwaway PostGIS database per test session, the real app, a live server.

Integration tests never mock the database: the session gets its own database, created on the
embedded cluster (or the server DATABASE_URL points at), migrated to head, and dropped at the end.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from app.db.session import _factory as session_factory
from app.db.session import get_engine
from app.routing.settings import routing_settings
from app.settings import get_settings
from testkit.scratch import scratch_database
from testkit.server import REPO, free_port, running_server

SHARED_DATA = REPO.parent / "shared" / "data"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu",
                  "--disable-background-networking"]


@contextmanager
def pointed_at_new_database(prefix: str, tmp_path_factory: pytest.TempPathFactory
                            ) -> Iterator[str]:
    """A fresh, migrated database with a raster store and data folder of its own, which
    ``DATABASE_URL``, ``UGVMAP_RASTER_STORE`` and ``UGVMAP_DATA_DIR`` name until the block ends
    (then they are what they were, and the database is dropped)."""
    keys = ("DATABASE_URL", "UGVMAP_RASTER_STORE", "UGVMAP_DATA_DIR")
    previous = {k: os.environ.get(k) for k in keys}
    with scratch_database(prefix) as url:
        os.environ["DATABASE_URL"] = url
        os.environ["UGVMAP_RASTER_STORE"] = str(tmp_path_factory.mktemp("rasters"))
        os.environ["UGVMAP_DATA_DIR"] = str(tmp_path_factory.mktemp("data"))
        forget_database()
        try:
            yield url
        finally:
            get_engine(url).dispose()
            for key, value in previous.items():
                if value is None:
                    os.environ.pop(key, None)
                else:
                    os.environ[key] = value
            forget_database()


def forget_database() -> None:
    """Drop what this process cached about the configured database (settings, the default
    engine and its session factory), so the next use reads the environment again."""
    get_settings.cache_clear()
    get_engine.cache_clear()
    session_factory.cache_clear()


@pytest.fixture(scope="session")
def database_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """URL of a fresh, migrated database that lives exactly as long as the test session."""
    with pointed_at_new_database("ugvmap_test", tmp_path_factory) as url:
        yield url


@pytest.fixture(scope="module")
def module_database(database_url: str, tmp_path_factory: pytest.TempPathFactory
                    ) -> Iterator[str]:
    """A database of the module's own, in place of the session's while the module runs: for
    tests whose cost grows with everything the other modules left in the shared database (the
    web map draws every layer and network there is)."""
    with pointed_at_new_database("ugvmap_module", tmp_path_factory) as url:
        yield url


@pytest.fixture()
def if_match_required(database_url: str, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """``UGVMAP_IF_MATCH=required`` for one test: writes without If-Match are a 428."""
    monkeypatch.setenv("UGVMAP_IF_MATCH", "required")
    get_settings.cache_clear()
    yield
    monkeypatch.delenv("UGVMAP_IF_MATCH")
    get_settings.cache_clear()


@pytest.fixture(scope="session")
def app(database_url: str):
    from app.main import create_app

    return create_app()


@pytest.fixture()
def client(app) -> Iterator:
    from fastapi.testclient import TestClient

    with TestClient(app) as c:
        yield c


@contextmanager
def settings_from_env(monkeypatch: pytest.MonkeyPatch, prefix: str, cached) -> Iterator:
    """A setter of ``prefix``-ed variables for one test (``set(max_points=3)``), clearing the
    ``cached`` settings reader after each change and at the end."""
    def set_values(**values: object) -> None:
        for key, value in values.items():
            monkeypatch.setenv(f"{prefix}{key.upper()}", str(value))
        cached.cache_clear()

    yield set_values
    monkeypatch.undo()
    cached.cache_clear()


@pytest.fixture()
def limits(monkeypatch: pytest.MonkeyPatch) -> Iterator:
    """Set routing limits through the environment for one test: ``limits(max_points=3)``."""
    with settings_from_env(monkeypatch, "UGVMAP_ROUTING_", routing_settings) as set_limits:
        yield set_limits


@pytest.fixture()
def heavy(monkeypatch: pytest.MonkeyPatch) -> Iterator:
    """Set the heavy-request lanes' limits for one test: ``heavy(running=1, waiting=0)``."""
    from app.lanes import lane_settings

    with settings_from_env(monkeypatch, "UGVMAP_HEAVY_", lane_settings) as set_limits:
        yield set_limits


@pytest.fixture(scope="session")
def live_server(database_url: str) -> Iterator[str]:
    """The real app served by uvicorn on a free localhost port, on the test database."""
    with running_server({"DATABASE_URL": database_url,
                         "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"]}) as base:
        yield base


@pytest.fixture(scope="module")
def browser() -> Iterator:
    """Debian's headless Chromium through Playwright (no browser download; WebGL on
    SwiftShader with --disable-gpu)."""
    if not CHROMIUM.exists():
        pytest.skip("Debian chromium not installed (scripts/setup.sh installs it)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_FLAGS)
        yield b
        b.close()


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared sample data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo):
    """Keep each phase's report on the item (``item.rep_call``), so fixtures can tell whether
    the test failed, e.g. to save a browser screenshot."""
    report = yield
    setattr(item, f"rep_{report.when}", report)
    return report


S3_ENV_KEYS = ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_REGION", "AWS_ENDPOINT_URL",
               "AWS_VIRTUAL_HOSTING", "AWS_S3_ENDPOINT", "AWS_HTTPS")


@pytest.fixture(scope="session")
def s3_endpoint() -> Iterator[str]:
    """A local S3-compatible server (moto's standalone server, real HTTP on a free port), with
    the AWS_* variables pointing at it the way a user would set them for MinIO."""
    from moto.server import ThreadedMotoServer

    previous = {k: os.environ.get(k) for k in S3_ENV_KEYS}
    port = free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    endpoint = f"http://127.0.0.1:{port}"
    os.environ.update({"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing",
                       "AWS_REGION": "us-east-1", "AWS_ENDPOINT_URL": endpoint,
                       "AWS_VIRTUAL_HOSTING": "FALSE"})
    try:
        yield endpoint
    finally:
        server.stop()
        for key, value in previous.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


@pytest.fixture()
def s3_store(s3_endpoint: str, database_url: str) -> Iterator[str]:
    """``UGVMAP_RASTER_STORE`` set to a fresh bucket on the local S3 server for one test.
    Afterwards the layers the test created are deleted with their objects: the catalogue
    holds keys relative to the configured store, so once the setting is restored they would
    point into the local store."""
    import uuid

    from sqlalchemy import text

    from app.tiles.catalog import delete_layer
    from app.tiles.store import RECORD_ROOT, open_store, recorded_root, s3_client

    def slugs() -> set[str]:
        with get_engine().connect() as conn:
            return set(conn.execute(text("SELECT slug FROM layers")).scalars())

    def record(root: str | None) -> None:
        """The store the database's files are in (migration 0009): the test's bucket while it
        runs, what it was afterwards."""
        with get_engine().begin() as conn:
            conn.execute(text("DELETE FROM raster_store"))
            if root is not None:
                conn.execute(text(RECORD_ROOT), {"root": root})

    before = slugs()
    bucket = f"ugvmap-{uuid.uuid4().hex[:8]}"
    s3_client().create_bucket(Bucket=bucket)
    previous = os.environ["UGVMAP_RASTER_STORE"]
    with get_engine().connect() as conn:
        previous_root = recorded_root(conn)
    os.environ["UGVMAP_RASTER_STORE"] = f"s3://{bucket}/rasters"
    get_settings.cache_clear()
    record(open_store().root)
    try:
        yield os.environ["UGVMAP_RASTER_STORE"]
    finally:
        with get_engine().begin() as conn:
            refs = [ref for slug in slugs() - before for ref in delete_layer(conn, slug) or []]
        open_store().delete(refs)
        os.environ["UGVMAP_RASTER_STORE"] = previous
        get_settings.cache_clear()
        record(previous_root)


@pytest.fixture(scope="session")
def drive(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The synthetic drive of ``tests/test_ipm_drive.py`` (frames, poses, calibration, roof
    mask), rendered once per session: that module and ``tests/test_ipm_roads.py`` ingest the
    same drive, and rendering it takes seconds. Tests only read it (a variant is a new file or
    a copy in the test's own folder)."""
    from ingest.ipm.synthetic import frame_times, write_drive
    from tests.test_ipm_drive import CAMERA, DRIVE, N_FRAMES

    return write_drive(tmp_path_factory.mktemp("drive"), DRIVE, CAMERA, frame_times(N_FRAMES))
