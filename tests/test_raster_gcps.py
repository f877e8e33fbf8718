"""Ground control points: residual report with known answers, warp accuracy, bad GCP files."""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np
import pytest
import rasterio.shutil
from click.testing import CliRunner
from pyproj import Transformer
from rasterio.env import get_gdal_config

from cli.main import main
from ingest.raster.cog import INGEST_BLOCK_CACHE_MB
from ingest.raster.gcps import read_gcps, residual_report
from ingest.raster.job import ingest_raster
from ingest.raster.sources import SourceError
from testkit.raster_synth import UTM33, mae, stitch, synthetic_utm, tiles_around, write_tif

W, H = 600, 400


def gcp_csv(path: Path, transform, points, shift=None, lonlat: bool = True) -> Path:
    """GCPs from the true transform; ``shift`` = {index: (dx, dy) metres} of survey error."""
    to_ll = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)
    lines = ["pixel_x,pixel_y,lon,lat,id" if lonlat else "pixel_x,pixel_y,e,n,id"]
    for i, (c, r) in enumerate(points):
        e, n = transform @ (c, r)
        dx, dy = (shift or {}).get(i, (0.0, 0.0))
        x, y = to_ll.transform(e + dx, n + dy) if lonlat else (e + dx, n + dy)
        lines.append(f"{c},{r},{x!r},{y!r},P{i}")
    path.write_text("\n".join(lines) + "\n")
    return path


GRID = [(c, r) for c in (20, 200, 400, 580) for r in (20, 200, 380)]


def plain_copy(src: Path, dst: Path) -> Path:
    import rasterio

    with rasterio.open(src) as ds:
        return write_tif(dst, ds.read(), None, None)


def test_affine_gcps_fit_exactly_and_tiles_match_geotiff(client, tmp_path: Path) -> None:
    tif, transform = synthetic_utm(tmp_path / "truth.tif", width=W, height=H)
    plain = plain_copy(tif, tmp_path / "photo.tif")
    csv_path = gcp_csv(tmp_path / "photo.csv", transform, GRID)
    report = residual_report(read_gcps(csv_path, None), "poly1", W, H)
    assert report.rmse_fit_m < 0.01 and report.rmse_loo_m < 0.01

    truth, warped = f"g-{uuid.uuid4().hex[:8]}", f"g-{uuid.uuid4().hex[:8]}"
    ingest_raster([tif], truth)
    result = CliRunner().invoke(main, ["ingest", "raster", str(plain), "--layer", warped,
                                       "--gcps", str(csv_path), "--gcp-method", "poly1"])
    assert result.exit_code == 0, result.output
    assert "RMSE" in result.output and "leave-1-out" in result.output
    info = client.get(f"/layers/{truth}").json()
    assert client.get(f"/layers/{warped}").json()["sources"][0]["georef"] == "gcps"
    w, s, e, n = info["bounds"]
    block = tiles_around((w + e) / 2, (s + n) / 2, info["maxzoom"], n=2)
    a = stitch(client.get, truth, info["maxzoom"], block)
    b = stitch(client.get, warped, info["maxzoom"], block)
    both = (a[..., 3] == 255) & (b[..., 3] == 255)
    assert both.mean() > 0.2
    assert mae(a[both][:, :3], b[both][:, :3]) < 2.0


def test_a_warped_ingest_writes_with_a_block_cache_and_leaves_one(
        database_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """GDAL has one block cache per process. The COGs were written with a cache of 256
    bytes (``rasterio.Env(GDAL_CACHEMAX=256)`` is bytes), and a GCP warp, which entered that
    ``Env`` with its source open, left the process's cache at 256 bytes: every later read in
    the process (a road extraction's mosaic) decoded each JPEG tile again per row."""
    tif, transform = synthetic_utm(tmp_path / "truth.tif", width=W, height=H)
    plain = plain_copy(tif, tmp_path / "photo.tif")
    csv_path = gcp_csv(tmp_path / "photo.csv", transform, GRID)
    seen: list[int] = []
    copy = rasterio.shutil.copy

    def copy_and_note_the_cache(*args, **kwargs):
        seen.append(get_gdal_config("GDAL_CACHEMAX"))
        return copy(*args, **kwargs)

    monkeypatch.setattr(rasterio.shutil, "copy", copy_and_note_the_cache)
    result = CliRunner().invoke(main, ["ingest", "raster", str(plain), "--layer",
                                       f"g-{uuid.uuid4().hex[:8]}", "--gcps", str(csv_path)])
    assert result.exit_code == 0, result.output
    cache = range(64 << 20, (INGEST_BLOCK_CACHE_MB << 20) + 1)  # megabytes, not bytes
    assert seen and all(size in cache for size in seen)
    assert get_gdal_config("GDAL_CACHEMAX") in cache


def test_tps_reports_leave_one_out_and_finds_the_bad_gcp(tmp_path: Path) -> None:
    _, transform = synthetic_utm(tmp_path / "t.tif", width=8, height=8)
    csv_path = gcp_csv(tmp_path / "bad.csv", transform, GRID, shift={4: (3.0, -2.0)},
                       lonlat=False)
    gcps = read_gcps(csv_path, "EPSG:32633")
    tps = residual_report(gcps, "tps", W, H)
    assert tps.rmse_fit_m is None and all(r.fit_m is None for r in tps.rows)
    worst = max(tps.rows, key=lambda r: r.loo_m)
    assert worst.id == "P4" and worst.loo_m > 2.0
    poly = residual_report(gcps, "poly1", W, H)
    # A least-squares fit spreads a 3.6 m blunder: its own residual is smaller than 3.6 m,
    # but still the largest, and the leave-one-out figure recovers most of it.
    assert max(poly.rows, key=lambda r: r.fit_m).id == "P4"
    assert 0 < poly.rmse_fit_m < poly.rmse_loo_m
    assert "P4" in tps.table() and "RMSE" in tps.table()


def test_quadratic_distortion_needs_poly2(tmp_path: Path) -> None:
    _, t = synthetic_utm(tmp_path / "t.tif", width=8, height=8)
    path = tmp_path / "quad.csv"
    rows = ["pixel_x,pixel_y,e,n"]
    for c, r in GRID:
        e, n = t @ (c, r)
        rows.append(f"{c},{r},{e + 1e-5 * c * c},{n + 2e-5 * c * r}")
    path.write_text("\n".join(rows))
    gcps = read_gcps(path, "EPSG:32633")
    assert residual_report(gcps, "poly2", W, H).rmse_fit_m < 1e-6
    assert residual_report(gcps, "poly1", W, H).rmse_fit_m > 0.1


@pytest.mark.parametrize("points, message", [
    ([(0, 0), (100, 0), (0, 100)], "needs at least 4"),
    ([(0, 0), (100, 100), (200, 200), (300, 300), (350, 350)], "degenerate"),
    ([(0, 0), (100, 0), (0, 100), (900, 900)], "inside"),
])
def test_bad_gcps_are_refused(tmp_path: Path, points, message) -> None:
    _, t = synthetic_utm(tmp_path / "t.tif", width=8, height=8)
    gcps = read_gcps(gcp_csv(tmp_path / "g.csv", t, points), None)
    with pytest.raises(SourceError, match=message):
        residual_report(gcps, "poly1", W, H)


def test_unparsable_gcp_file(tmp_path: Path) -> None:
    path = tmp_path / "junk.csv"
    path.write_text("pixel_x,pixel_y,lon,lat\n1,2,three,4\n")
    with pytest.raises(SourceError, match="expected pixel_x"):
        read_gcps(path, None)
    path.write_text("# nothing\n")
    with pytest.raises(SourceError, match="no ground control points"):
        read_gcps(path, None)
    assert np.isfinite(read_gcps(gcp_csv(path, synthetic_utm(tmp_path / "x.tif", 8, 8)[1],
                                         GRID), None).coords).all()
