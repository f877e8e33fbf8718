"""The one tile grid and coordinate helpers every capability uses.

Raster tiles, vector tiles and ingest all work on OGC's WebMercatorQuad tile-matrix set
(morecantile's definition), so a tile address means the same thing everywhere and the largest
zoom comes from one place: the set itself.
"""

from __future__ import annotations

import morecantile

from app.errors import InvalidParameterValueError, TileOutOfRangeError

TMS = morecantile.tms.get("WebMercatorQuad")
MAX_ZOOM: int = TMS.maxzoom


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
