"""One data directory whatever the working directory (issue 22): ``ugvmap`` run from another
folder reaches the same raster store as the server, a process configured with another store
is refused at ingest (and not ready), a missing COG is an error rather than a blank tile, and
``db status`` says where everything is."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import uuid
from pathlib import Path

import httpx
import pytest
from sqlalchemy import create_engine, text

from app.settings import CHECKOUT
from app.tiles.store import RECORD_ROOT
from testkit.raster_synth import TMS, decode_rgba, synthetic_utm, utm_origin
from testkit.scratch import scratch_database
from testkit.server import running_server
from tests.conftest import REPO

STORE_VARIABLES = ("UGVMAP_RASTER_STORE", "UGVMAP_DATA_DIR")
DEFAULT_STORE = CHECKOUT / ".data" / "rasters"


def _cli(cwd: Path, env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    """``ugvmap ARGS`` in ``cwd`` with the default data directory (no store variables but
    those in ``env``)."""
    clean = {k: v for k, v in os.environ.items() if k not in STORE_VARIABLES}
    return subprocess.run([sys.executable, "-m", "cli", *args], cwd=cwd, capture_output=True,
                          env={**clean, **env, "PYTHONPATH": str(REPO)}, text=True,
                          timeout=300)


def test_the_data_directory_does_not_depend_on_the_working_directory(tmp_path: Path) -> None:
    """It used to be ``.data`` under the working directory."""
    code = ("from app.settings import get_settings as g; s = g(); "
            "print(s.data_dir, s.raster_store_uri, s.pg_data_dir)")
    seen = set()
    for cwd in (REPO, tmp_path, tmp_path.parent):
        clean = {k: v for k, v in os.environ.items() if k not in STORE_VARIABLES}
        out = subprocess.run([sys.executable, "-c", code], cwd=cwd, text=True, check=True,
                             capture_output=True, env={**clean, "PYTHONPATH": str(REPO)})
        seen.add(out.stdout.strip())
    assert seen == {f"{CHECKOUT / '.data'} {DEFAULT_STORE} {CHECKOUT / '.data' / 'postgres'}"}


def test_ingest_from_another_folder_is_served_with_its_pixels(tmp_path: Path) -> None:
    """The user's report: ``ugvmap ingest raster`` from another folder, the server started in
    the checkout, both with the defaults: the tiles now show the image (they were
    transparent 200s); a process set to another store is refused and writes nothing."""
    elsewhere = tmp_path / "somewhere" / "else"
    elsewhere.mkdir(parents=True)
    image, _ = synthetic_utm(tmp_path / "survey.tif", width=256, height=256)
    slug = f"cwd-{uuid.uuid4().hex[:8]}"
    with scratch_database("ugvmap_datadir") as url:
        env = {"DATABASE_URL": url}
        ingest = _cli(elsewhere, env, "ingest", "raster", str(image), "--layer", slug)
        assert ingest.returncode == 0, ingest.stderr
        try:
            assert str(DEFAULT_STORE / slug) in ingest.stdout
            status = _cli(elsewhere, env, "db", "status")
            assert status.returncode == 0, status.stderr
            assert f"data directory {CHECKOUT / '.data'}" in status.stdout
            assert "the database's rasters are in this store" in status.stdout

            with running_server(env, drop=STORE_VARIABLES) as base:
                assert httpx.get(f"{base}/readyz").status_code == 200
                tile = TMS.tile(*_centre(), 17)
                r = httpx.get(f"{base}/tiles/{slug}/17/{tile.x}/{tile.y}.png")
                assert r.status_code == 200
                assert decode_rgba(r.content)[..., 3].max() == 255  # pixels, not blank

            other = tmp_path / "other-store"
            refused = _cli(elsewhere, {**env, "UGVMAP_RASTER_STORE": str(other)}, "ingest",
                           "raster", str(image), "--layer", f"{slug}-b")
            assert refused.returncode == 1 and "Traceback" not in refused.stderr
            assert str(DEFAULT_STORE) in refused.stderr and str(other) in refused.stderr
            assert not other.exists() or not any(other.rglob("*.tif"))
            status = _cli(elsewhere, {**env, "UGVMAP_RASTER_STORE": str(other)}, "db",
                          "status")
            assert status.returncode == 1 and str(DEFAULT_STORE) in status.stderr
        finally:
            deleted = _cli(elsewhere, env, "layers", "delete", slug, "--yes")
            assert deleted.returncode == 0, deleted.stderr
        folder = DEFAULT_STORE / slug
        assert not folder.exists() or not any(folder.iterdir())  # the files went with it
        if folder.exists():
            folder.rmdir()


def _centre() -> tuple[float, float]:
    """Lon/lat of the middle of ``synthetic_utm``'s 256 px at 0.3 m."""
    from pyproj import Transformer

    east, north = utm_origin()
    return Transformer.from_crs("EPSG:32633", "EPSG:4326", always_xy=True).transform(
        round(east) + 38.4, round(north) - 38.4)


def test_a_missing_cog_is_an_error_not_a_blank_tile(client, tmp_path: Path, caplog) -> None:
    from ingest.raster.job import ingest_raster

    image, _ = synthetic_utm(tmp_path / "gone.tif", width=256, height=256)
    slug = f"gone-{uuid.uuid4().hex[:8]}"
    report = ingest_raster([image], slug)
    store = Path(os.environ["UGVMAP_RASTER_STORE"])
    (store / report.sources[0].uri).unlink()
    caplog.set_level(logging.ERROR, logger="app.tiles.mosaic")
    tile = TMS.tile(*_centre(), 18)
    r = client.get(f"/tiles/{slug}/18/{tile.x}/{tile.y}.png")
    assert (r.status_code, r.json()["code"]) == (500, "RasterSourceMissing")
    assert str(store) not in r.text  # server paths are for the operator
    assert report.sources[0].uri in caplog.text


def test_readyz_refuses_a_process_reading_another_store(client, database_url: str) -> None:
    engine = create_engine(database_url)
    with engine.begin() as conn:
        previous = conn.execute(text("SELECT root FROM raster_store")).scalar()
        conn.execute(text(RECORD_ROOT), {"root": "/somewhere/else/rasters"})
    try:
        r = client.get("/readyz")
        assert (r.status_code, r.json()["code"]) == (503, "StoreMismatch")
        assert "/somewhere" not in r.text
    finally:
        with engine.begin() as conn:
            conn.execute(text("DELETE FROM raster_store"))
            if previous is not None:
                conn.execute(text(RECORD_ROOT), {"root": previous})
        engine.dispose()
    assert client.get("/readyz").status_code == 200


def test_an_explicit_relative_data_dir_is_resolved_once(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """A relative ``UGVMAP_DATA_DIR`` means the folder where it was given, not wherever a
    later call happens to run."""
    from app.settings import Settings

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("UGVMAP_DATA_DIR", "mydata")
    monkeypatch.delenv("UGVMAP_RASTER_STORE")
    settings = Settings()
    monkeypatch.chdir(REPO)
    assert settings.data_dir == tmp_path / "mydata"
    assert settings.raster_store_uri == str(tmp_path / "mydata" / "rasters")
