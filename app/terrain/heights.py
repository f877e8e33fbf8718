"""Heights at points of an elevation layer: bilinear between the four nearest pixel centres
of the finest source that has all four, null where no source does (outside, or nodata).

One 2 x 2 read per point and source: a route's few thousand points cost milliseconds, and
the read is at the source's full resolution whatever the points' spread (a window around
them all could be a whole survey).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from pyproj import Transformer
from rasterio.windows import Window
from sqlalchemy import Connection

from app.errors import InvalidParameterValueError, LayerNotFoundError
from app.tiles.catalog import TileSource, layer_row, tile_sources
from app.tiles.placement import open_source

TO_3857 = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)


def elevation_sources(conn: Connection, slug: str,
                      bbox: tuple[float, float, float, float]) -> list[TileSource]:
    """The sources of elevation layer ``slug`` meeting ``bbox`` (EPSG:3857), top first;
    404 for no such layer, 400 for a layer that holds no heights."""
    row = layer_row(conn, slug)
    if row is None:
        raise LayerNotFoundError(f"no raster layer {slug[:100]!r}")
    if row["kind"] != "elevation":
        raise InvalidParameterValueError(
            f"layer {slug} is an {row['kind']} layer, not an elevation layer (ingest a DEM "
            "with --kind elevation)")
    query = tile_sources(conn, slug, bbox)
    assert query is not None
    return query.sources[::-1]


def bilinear_at(source: TileSource, x: float, y: float) -> float | None:
    """The source's height at EPSG:3857 ``x, y``, or None when any of the four pixels around
    it is outside the source or nodata."""
    ds = open_source(source)
    col = (x - ds.transform.c) / ds.transform.a - 0.5
    row = (y - ds.transform.f) / ds.transform.e - 0.5
    c0, r0 = math.floor(col), math.floor(row)
    if c0 < 0 or r0 < 0 or c0 + 1 >= ds.width or r0 + 1 >= ds.height:
        return None
    window = Window(c0, r0, 2, 2)
    if not (ds.read_masks(1, window=window) > 0).all():
        return None
    z = ds.read(1, window=window, out_dtype=np.float64)
    fx, fy = col - c0, row - r0
    top = z[0, 0] * (1 - fx) + z[0, 1] * fx
    bottom = z[1, 0] * (1 - fx) + z[1, 1] * fx
    return float(top * (1 - fy) + bottom * fy)


def ground(conn: Connection, slug: str) -> Callable[[np.ndarray], np.ndarray]:
    """Heights of elevation layer ``slug`` for arrays of lon/lat rows (NaN where it has
    none), for exports that write a height per point (Lanelet2's ``ele``); the layer is
    checked at once, so a wrong slug fails before anything is written."""
    elevation_sources(conn, slug, (0.0, 0.0, 0.0, 0.0))

    def at(lonlat: np.ndarray) -> np.ndarray:
        found = heights_at(conn, slug, [(float(x), float(y)) for x, y in lonlat])
        return np.array([np.nan if h is None else h for h in found], np.float64)
    return at


def heights_at(conn: Connection, slug: str,
               lonlats: Sequence[tuple[float, float]]) -> list[float | None]:
    """Heights of elevation layer ``slug`` at each lon/lat (None: no data there)."""
    if not lonlats:
        return []
    xs, ys = TO_3857.transform([p[0] for p in lonlats], [p[1] for p in lonlats])
    sources = elevation_sources(conn, slug, (min(xs), min(ys), max(xs), max(ys)))
    out: list[float | None] = []
    for x, y in zip(xs, ys, strict=True):
        out.append(next((h for s in sources if (h := bilinear_at(s, x, y)) is not None), None))
    return out
