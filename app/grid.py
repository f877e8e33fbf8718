"""The one tile grid and coordinate helpers every capability uses.

Raster tiles, vector tiles and ingest all work on OGC's WebMercatorQuad tile-matrix set
(morecantile's definition), so a tile address means the same thing everywhere, the largest
zoom comes from the set itself, and resolutions come from its matrices rather than from
hand-copied earth constants. Metric work near a point (GCP fits, snapping fractions) uses the
point's UTM zone, chosen by :func:`utm_epsg` alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import morecantile
from rasterio.transform import Affine, from_origin

from app.errors import InvalidParameterValueError, TileOutOfRangeError

TMS = morecantile.tms.get("WebMercatorQuad")
MAX_ZOOM: int = TMS.maxzoom
TILE_SIZE = 256
Bounds = tuple[float, float, float, float]  # left, bottom, right, top (EPSG:3857 metres)


def parse_tile(z: str, x: str, y: str) -> tuple[int, int, int]:
    """A tile address from URL parts: 400 when a part is not a non-negative integer (the
    address is malformed), 404 when it is well formed but outside the tile-matrix set."""
    if not all(p.isascii() and p.isdigit() for p in (z, x, y)):
        raise InvalidParameterValueError(
            f"tile address {z[:20]}/{x[:20]}/{y[:20]}: z, x and y must be non-negative integers")
    zi, xi, yi = int(z), int(x), int(y)
    if zi > MAX_ZOOM or xi >= 2**zi or yi >= 2**zi:
        raise TileOutOfRangeError(
            f"tile {z[:20]}/{x[:20]}/{y[:20]} is outside the grid (z 0..{MAX_ZOOM}, "
            "x and y 0..2^z-1)")
    return zi, xi, yi


def tile_bounds(z: int, x: int, y: int) -> Bounds:
    """The tile's extent in EPSG:3857."""
    b = TMS.xy_bounds(morecantile.Tile(x, y, z))
    return (b.left, b.bottom, b.right, b.top)


def pixel_size_m(zoom: int) -> float:
    """EPSG:3857 metres per pixel of a 256 px tile at ``zoom`` (true size at the equator)."""
    return float(TMS.matrix(zoom).cellSize)


def ground_resolution_m(zoom: int, lat: float) -> float:
    """True metres per pixel at ``zoom`` and latitude ``lat`` (mercator scale is 1/cos)."""
    return pixel_size_m(zoom) * math.cos(math.radians(lat))


def zoom_for_pixel_size(res_3857: float) -> int:
    """The zoom whose pixels are closest to ``res_3857`` EPSG:3857 metres (GDAL's rule)."""
    return int(TMS.zoom_for_res(res_3857, zoom_level_strategy="auto"))


@dataclass(frozen=True)
class TileBlock:
    """A rectangle of whole tiles at one zoom: a raster written on it is block-aligned with
    the XYZ grid, so serving a tile at that zoom is one block read."""

    zoom: int
    col0: int
    row0: int
    cols: int
    rows: int

    @property
    def transform(self) -> Affine:
        """Affine transform of the block's top-left pixel at the zoom's resolution."""
        res = pixel_size_m(self.zoom)
        left, _, _, top = tile_bounds(self.zoom, self.col0, self.row0)
        return from_origin(left, top, res, res)

    @property
    def width(self) -> int:
        """Width in pixels: whole tiles only."""
        return self.cols * TILE_SIZE

    @property
    def height(self) -> int:
        """Height in pixels: whole tiles only."""
        return self.rows * TILE_SIZE

    def tiles(self) -> list[tuple[int, int]]:
        """(x, y) of every tile, row by row."""
        return [(self.col0 + c, self.row0 + r) for r in range(self.rows)
                for c in range(self.cols)]


def covering_block(bounds: Bounds, zoom: int) -> TileBlock:
    """The smallest block of tiles at ``zoom`` that covers ``bounds`` (snapped outwards)."""
    origin_x, origin_y = TMS.matrix(zoom).pointOfOrigin
    span = pixel_size_m(zoom) * TILE_SIZE
    # A bound within 1e-6 tile of a tile edge is on it (rounding, not an extra empty tile).
    col0 = math.floor((bounds[0] - origin_x) / span + 1e-6)
    row0 = math.floor((origin_y - bounds[3]) / span + 1e-6)
    col1 = max(col0 + 1, math.ceil((bounds[2] - origin_x) / span - 1e-6))
    row1 = max(row0 + 1, math.ceil((origin_y - bounds[1]) / span - 1e-6))
    return TileBlock(zoom, col0, row0, col1 - col0, row1 - row0)


def utm_epsg(lon: float, lat: float) -> int:
    """EPSG code of the WGS 84 UTM zone containing lon/lat (lon 180 counts as zone 60)."""
    zone = min(60, int((lon + 180) // 6) + 1)
    return (32600 if lat >= 0 else 32700) + zone
