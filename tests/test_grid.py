"""The one tile grid: resolutions from the tile-matrix set, outward snapping, UTM zones."""

from __future__ import annotations

import pytest

from app.errors import InvalidParameterValueError, TileOutOfRangeError
from app.grid import (
    MAX_ZOOM,
    covering_block,
    ground_resolution_m,
    parse_tile,
    pixel_size_m,
    tile_bounds,
    utm_epsg,
    zoom_for_pixel_size,
)


def test_resolutions_match_the_web_mercator_constants() -> None:
    assert pixel_size_m(0) == pytest.approx(156543.03392804097)
    assert pixel_size_m(18) == pytest.approx(156543.03392804097 / 2**18)
    assert ground_resolution_m(0, 60.0) == pytest.approx(156543.03392804097 / 2)
    assert zoom_for_pixel_size(pixel_size_m(17) * 1.2) == 17  # closest zoom, not the finer one


def test_covering_block_snaps_outwards_to_whole_tiles() -> None:
    left, bottom, right, top = tile_bounds(12, 100, 200)
    inner = (left + 1, bottom + 1, right + 1, top - 1)  # spills one metre into the next column
    block = covering_block(inner, 12)
    assert (block.col0, block.row0, block.cols, block.rows) == (100, 200, 2, 1)
    assert block.transform.c == pytest.approx(left) and block.transform.f == pytest.approx(top)
    assert (block.width, block.height) == (512, 256)
    assert block.tiles() == [(100, 200), (101, 200)]
    exact = covering_block((left, bottom, right, top), 12)  # exactly one tile: no extra column
    assert (exact.cols, exact.rows) == (1, 1)


@pytest.mark.parametrize(("lon", "lat", "epsg"), [
    (15.2, 48.3, 32633), (-115.2, 36.2, 32611), (-180.0, 10.0, 32601), (180.0, 10.0, 32660),
    (24.9, -33.9, 32735), (0.0, 0.0, 32631)])
def test_utm_zone(lon: float, lat: float, epsg: int) -> None:
    assert utm_epsg(lon, lat) == epsg


def test_tile_address_rule() -> None:
    assert parse_tile("3", "7", "0") == (3, 7, 0)
    assert parse_tile(str(MAX_ZOOM), "0", "0") == (MAX_ZOOM, 0, 0)
    for bad in (("3", "8", "0"), (str(MAX_ZOOM + 1), "0", "0")):
        with pytest.raises(TileOutOfRangeError):
            parse_tile(*bad)
    for bad in (("3", "-1", "0"), ("٣", "0", "0"), ("3", "", "0")):
        with pytest.raises(InvalidParameterValueError):
            parse_tile(*bad)
