"""Zone stitching without a database: blend modes, bounded memory, passes, slivers, and the
written zone mosaics being what ``ingest raster`` reads."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio

from ingest.ipm.grid import ZoneGrid
from ingest.ipm.place import PlacedPatch
from ingest.ipm.stitch import ZoneStitcher
from ingest.raster.georef import ZoneSidecar
from ingest.raster.sources import inspect

GRID = ZoneGrid(17.6, 48.15, zone_size_px=(512, 512), overlap_px=(32, 32))


def patch(col0: int, row0: int, size: int, value: int, cam: tuple[float, float],
          valid: np.ndarray | None = None) -> PlacedPatch:
    r, c = np.mgrid[0:size, 0:size].astype(np.float32) + 0.5
    dist2 = (c + col0 - cam[0]) ** 2 + (r + row0 - cam[1]) ** 2
    return PlacedPatch(col0, row0, np.full((size, size, 3), value, np.uint8),
                       np.ones((size, size), bool) if valid is None else valid, dist2)


def read_zone(path: Path) -> np.ndarray:
    with rasterio.open(path) as ds:
        return ds.read()


@pytest.mark.parametrize(("blend", "expected"), [("nearest", 50), ("later", 200),
                                                 ("weighted", None)])
def test_blend_modes(tmp_path: Path, blend: str, expected: int | None) -> None:
    stitcher = ZoneStitcher(GRID, blend, tmp_path, reach_px=1e9)
    # Pixel (100, 100): the first frame saw it from 10 px, the second from 60 px.
    stitcher.add(patch(50, 50, 100, 50, cam=(110, 100)))
    stitcher.add(patch(90, 90, 100, 200, cam=(160, 100)))
    stitcher.close_all()
    assert stitcher.written == [tmp_path / "zone_r0_c0.tif"]
    data = read_zone(stitcher.written[0])
    value = int(data[0, 100, 100])
    if expected is None:
        w1, w2 = 1 / (10.5**2 + 0.25 + (1 / 0.06) ** 2), 1 / (59.5**2 + 0.25 + (1 / 0.06) ** 2)
        expected = round((50 * w1 + 200 * w2) / (w1 + w2))
    assert value == pytest.approx(expected, abs=1)
    assert data[3, 100, 100] == 255 and data[3, 10, 10] == 0 and data[3, 189, 189] == 255
    assert int(data[0, 60, 60]) == 50 and int(data[0, 185, 185]) == 200  # seen once


def test_a_long_drive_keeps_few_zones_open(tmp_path: Path) -> None:
    stitcher = ZoneStitcher(GRID, "nearest", tmp_path, reach_px=300)
    size = 250
    for i in range(400):  # 10 px per frame eastwards: 4000 px
        col, row = 10 * i, 500  # rows 375..625: zone rows 0 and 1 overlap at 480..512
        stitcher.add(patch(col - size // 2, row - size // 2, size, 40 + i % 200, (col, row)))
        stitcher.close_far(col, row)
    stitcher.close_all()
    stats = stitcher.stats
    assert stats.zones_written == 20  # columns -1..8, rows 0 and 1
    assert stats.peak_open_zones <= 6
    # Memory follows the open zones' covered chunks, never the whole drive.
    assert stats.peak_bytes <= 6 * 4 * 256 * 256 * 7
    assert stats.covered_px == (4000 - 10 + size) * size
    for path in stitcher.written:
        zone = ZoneSidecar.load(path.with_name(path.name + ".zone.json"))
        source = inspect(path)
        assert source.georef_from == "zone" and source.has_mask
        with rasterio.open(path) as ds:
            assert ds.transform.almost_equals(zone.transform())
            assert ds.crs == zone.crs()


def test_coming_back_starts_a_new_pass(tmp_path: Path) -> None:
    stitcher = ZoneStitcher(GRID, "later", tmp_path, reach_px=100)
    stitcher.add(patch(100, 100, 100, 60, (150, 150)))
    stitcher.close_far(2000, 150)  # drove away: zone 0/0 written
    stitcher.add(patch(120, 100, 100, 90, (170, 150)))  # and came back
    stitcher.close_all()
    names = sorted(p.name for p in stitcher.written)
    assert names == ["zone_r0_c0.tif", "zone_r0_c0_pass2.tif"]
    doc = json.loads((tmp_path / "zone_r0_c0_pass2.tif.zone.json").read_text())
    assert doc["zone"] == {"row": 0, "col": 0}
    assert int(read_zone(tmp_path / "zone_r0_c0_pass2.tif")[0, 150, 200]) == 90


def test_slivers_are_dropped(tmp_path: Path) -> None:
    stitcher = ZoneStitcher(GRID, "nearest", tmp_path, reach_px=1e9)
    valid = np.zeros((100, 100), bool)
    valid[:, 50] = True  # a one-pixel line
    stitcher.add(patch(0, 0, 100, 80, (0, 0), valid))
    stitcher.close_all()
    # Zones (-1, 0) and (0, 0) each got part of the line; no other zone was opened.
    assert stitcher.written == [] and stitcher.stats.zones_dropped == 2
