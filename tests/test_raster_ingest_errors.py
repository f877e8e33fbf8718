"""Bad inputs are refused with one clear CLI line and change neither the catalogue nor the store;
a killed ingest leaves no half-registered layer and nothing that would be served."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from rasterio.crs import CRS
from rasterio.transform import from_origin
from sqlalchemy import text

from app.db.session import get_engine
from app.settings import get_settings
from cli.main import main
from testkit.raster_synth import UTM33, pattern_image, synthetic_utm, write_tif
from tests.conftest import REPO


def snapshot() -> tuple:
    """Everything an ingest could change: catalogue rows and every file in the store."""
    with get_engine().connect() as conn:
        layers = conn.execute(text("SELECT slug, version FROM layers ORDER BY slug")).all()
        sources = conn.execute(text("SELECT uri FROM raster_sources ORDER BY uri")).all()
    store = Path(get_settings().raster_store_uri)
    files = sorted(str(p) for p in store.rglob("*")) if store.exists() else []
    return layers, sources, files


def run_cli(*args: str):
    return CliRunner().invoke(main, list(args))


@pytest.fixture()
def existing_layer(database_url: str, tmp_path: Path) -> str:
    name = f"keep-{uuid.uuid4().hex[:8]}"
    path, _ = synthetic_utm(tmp_path / "ok.tif", width=200, height=200)
    assert run_cli("ingest", "raster", str(path), "--layer", name).exit_code == 0
    return name


def bad_inputs(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    text_file = tmp_path / "notes.tif"
    text_file.write_text("this is not an image\n" * 50)
    empty = tmp_path / "empty.tif"
    empty.write_bytes(b"")
    good, transform = synthetic_utm(tmp_path / "full.tif", width=600, height=600)
    truncated = tmp_path / "truncated.tif"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size * 6 // 10])
    no_header = tmp_path / "no_header.tif"  # a TIFF signature, then zeros where its IFD was
    no_header.write_bytes(good.read_bytes()[:8] + bytes(200) + good.read_bytes()[208:])
    plain = tmp_path / "plain.png"
    import cv2

    cv2.imwrite(str(plain), np.zeros((50, 50, 3), np.uint8))
    bad_world = tmp_path / "zero.png"
    cv2.imwrite(str(bad_world), np.zeros((50, 50, 3), np.uint8))
    bad_world.with_suffix(".pgw").write_text("0\n0\n0\n0\n500000\n5000000\n")
    absurd_res = write_tif(tmp_path / "tiny_pixels.tif", pattern_image(transform, 64, 64),
                           UTM33, transform @ transform.scale(1e-5))
    polar = from_origin(10.0, 89.0, 0.001, 0.001)  # north of web mercator's 85.05 deg
    off_world = write_tif(tmp_path / "off_world.tif", pattern_image(transform, 64, 64),
                          CRS.from_epsg(4326), polar)
    return {
        "text": (text_file, "notes.tif: not an image: its content is in no raster format "
                            "GDAL reads (GeoTIFF, PNG, JPEG, ... were expected)"),
        "empty": (empty, "empty file"),
        "truncated": (truncated, "truncated.tif: a damaged image: pixel row 600 of 600 cannot "
                                 "be read (the file is cut short or corrupt)"),
        "corrupt header": (no_header, "no_header.tif: a damaged image: its header cannot be "
                                      "read (the file is cut short or corrupt)"),
        "no georef": (plain, "not georeferenced"),
        "degenerate world file": (bad_world, "degenerate world file"),
        "absurd resolution": (absurd_res, "not plausible"),
        "off the map": (off_world, "outside the web-mercator world"),
        "missing": (tmp_path / "nope.tif", "no such file"),
    }


def test_bad_inputs_refused_and_nothing_changes(existing_layer: str, tmp_path: Path) -> None:
    good, _ = synthetic_utm(tmp_path / "good.tif", width=100, height=100)
    for case, (path, message) in bad_inputs(tmp_path).items():
        before = snapshot()
        # Also with a valid file first: validation runs before anything is written.
        for layer in (existing_layer, f"new-{uuid.uuid4().hex[:6]}"):
            result = run_cli("ingest", "raster", str(good), str(path), "--layer", layer,
                             "--crs", "EPSG:32633")
            assert result.exit_code == 1, (case, result.output)
            assert message in result.output, (case, result.output)
            assert "Traceback" not in result.output
            assert "See previous exception" not in result.output and "TIFF" not in \
                result.output.replace("GeoTIFF", ""), result.output
            assert len(result.output.strip().splitlines()) == 1, result.output
        assert snapshot() == before, case


def test_bad_slug_and_unknown_layer_cli(database_url: str, tmp_path: Path) -> None:
    good, _ = synthetic_utm(tmp_path / "g.tif", width=64, height=64)
    result = run_cli("ingest", "raster", str(good), "--layer", "Bad Slug!")
    assert result.exit_code == 1 and "slug" in result.output
    for sub in ("show", "delete"):
        result = run_cli("layers", sub, "no-such-layer")
        assert result.exit_code == 1 and "no raster layer" in result.output


def test_layers_cli_list_show_delete(existing_layer: str) -> None:
    listed = run_cli("layers", "list")
    assert listed.exit_code == 0 and existing_layer in listed.output
    shown = run_cli("layers", "show", existing_layer)
    assert shown.exit_code == 0 and "georef=file" in shown.output
    uri = shown.output.strip().splitlines()[-1].split()[-1]
    assert Path(uri).is_file()
    deleted = run_cli("layers", "delete", existing_layer, "--yes")
    assert deleted.exit_code == 0
    assert not Path(uri).exists()
    assert existing_layer not in run_cli("layers", "list").output


@pytest.mark.slow
def test_killed_ingest_leaves_no_half_registered_layer(database_url: str, tmp_path: Path,
                                                      client) -> None:
    big = tmp_path / "big.tif"
    rng = np.random.default_rng(0)
    _, transform = synthetic_utm(tmp_path / "unused.tif", width=8, height=8)
    write_tif(big, rng.integers(0, 255, (3, 5000, 5000), dtype=np.uint8), UTM33, transform,
              tiled=True)
    name = f"killed-{uuid.uuid4().hex[:6]}"
    layer_dir = Path(get_settings().raster_store_uri) / name
    proc = subprocess.Popen([sys.executable, "-m", "cli", "ingest", "raster", str(big),
                             "--layer", name], cwd=REPO, env=os.environ.copy(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not list(layer_dir.glob(".*.tmp*")):
        assert proc.poll() is None, "ingest finished before it could be killed"
        assert time.monotonic() < deadline
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with get_engine().connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM layers WHERE slug = :s"),
                            {"s": name}).scalar() == 0
    # Only hidden temporary files may remain: nothing under a final name.
    assert [p for p in layer_dir.iterdir() if not p.name.startswith(".")] == []
    assert client.get(f"/tiles/{name}/0/0/0.png").status_code == 404
    # And the job can simply be re-run; it sweeps the dead job's leftovers.
    small, _ = synthetic_utm(tmp_path / "small.tif", width=100, height=100)
    assert run_cli("ingest", "raster", str(small), "--layer", name).exit_code == 0
    assert client.get(f"/layers/{name}").json()["source_count"] == 1
    assert not list(layer_dir.glob(".*"))
    assert len(list(layer_dir.iterdir())) == 2  # the new source and the layer overview


def test_demo_loader_ingests_samples_once(database_url: str, shared_data: Path) -> None:
    from ingest.raster.samples import SAMPLE_LAYERS, ingest_sample_orthophotos

    first = ingest_sample_orthophotos(shared_data / "orthophotos")
    assert {r.layer for r in first} <= set(SAMPLE_LAYERS)
    assert ingest_sample_orthophotos(shared_data / "orthophotos") == []
    listed = run_cli("layers", "list").output
    assert all(slug in listed for slug in SAMPLE_LAYERS)


def test_failed_cog_write_leaves_no_temporary_file(tmp_path: Path) -> None:
    """A source whose blocks stop halfway (readable header, cut data) fails inside GDAL's
    warp: neither our temporary COG nor GDAL's ``*.warped.tif.tmp`` (named from ours, in
    ``CPL_TMPDIR``) may stay beside the destination."""
    import rasterio
    from rasterio._err import CPLE_BaseError
    from rasterio.transform import from_bounds

    from ingest.raster.cog import write_cog

    src = tmp_path / "cut.tif"
    with rasterio.open(src, "w", driver="GTiff", width=2000, height=2000, count=3,
                       dtype="uint8", crs="EPSG:4326",
                       transform=from_bounds(10, 50, 10.03, 50.03, 2000, 2000)) as ds:
        ds.write(np.random.default_rng(0).integers(0, 255, (3, 2000, 2000), dtype=np.uint8))
    with src.open("r+b") as f:
        f.truncate(src.stat().st_size // 2)
    out = tmp_path / "store"
    with pytest.raises(CPLE_BaseError, match="IReadBlock failed"):
        write_cog(src, out / "x.tif", "uint8", 3)
    assert list(out.iterdir()) == []
