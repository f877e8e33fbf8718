"""Layer-level overview: one small COG of the whole layer for low zooms.

Without it, a low-zoom tile over a city-wide survey would open every zone COG that meets it.
The overview is the layer rendered at ``maxzoom - OVERVIEW_DEPTH`` (coarser if the layer is
spread out, so it never exceeds ``MAX_TILES_PER_SIDE`` tiles a side) by the *same*
composition code that serves tiles (:func:`app.tiles.mosaic.render`), one 256 px tile at a
time into a temporary tiled GeoTIFF, then written as a COG with its own overviews. Tiles at
or below its zoom read only this file; finer tiles read the sources.
"""

from __future__ import annotations

import math
from pathlib import Path

import morecantile
import numpy as np
import rasterio
from rasterio.transform import from_origin
from rasterio.windows import Window

from app.tiles.catalog import TileSource
from app.tiles.mosaic import render
from ingest.raster.cog import GDAL_CACHEMAX_MB, TILE_SIZE, write_cog

OVERVIEW_DEPTH = 5
MAX_TILES_PER_SIDE = 32
TMS = morecantile.tms.get("WebMercatorQuad")


def overview_zoom(bounds_3857: tuple[float, float, float, float], maxzoom: int) -> int:
    """Finest zoom <= maxzoom - OVERVIEW_DEPTH at which the layer spans few enough tiles."""
    world = TMS.xy_bounds(0, 0, 0)
    span = max(bounds_3857[2] - bounds_3857[0], bounds_3857[3] - bounds_3857[1])
    zoom = max(0, maxzoom - OVERVIEW_DEPTH)
    while zoom > 0 and span / ((world.right - world.left) / 2**zoom) > MAX_TILES_PER_SIDE - 1:
        zoom -= 1
    return zoom


def build_overview(sources: list[TileSource], bounds_3857: tuple[float, float, float, float],
                   maxzoom: int, dst: Path) -> int:
    """Render the layer into ``dst`` (COG, 8-bit RGB + mask); return the overview zoom."""
    zoom = overview_zoom(bounds_3857, maxzoom)
    world = TMS.xy_bounds(0, 0, 0)
    span = (world.right - world.left) / 2**zoom
    x0 = math.floor((bounds_3857[0] - world.left) / span)
    x1 = math.floor((bounds_3857[2] - world.left) / span)
    y0 = math.floor((world.top - bounds_3857[3]) / span)
    y1 = math.floor((world.top - bounds_3857[1]) / span)
    res = span / TILE_SIZE
    profile = {"driver": "GTiff", "width": (x1 - x0 + 1) * TILE_SIZE,
               "height": (y1 - y0 + 1) * TILE_SIZE, "count": 4, "dtype": "uint8",
               "crs": "EPSG:3857", "photometric": "RGB", "alpha": "YES",
               "transform": from_origin(world.left + x0 * span, world.top - y0 * span, res, res),
               "tiled": True, "blockxsize": TILE_SIZE, "blockysize": TILE_SIZE,
               "compress": "zstd", "sparse_ok": True}
    tmp = dst.with_name(f".{dst.name}.mosaic.tmp")
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHEMAX_MB), \
                rasterio.open(tmp, "w", **profile) as out:
            for y in range(y0, y1 + 1):
                for x in range(x0, x1 + 1):
                    b = TMS.xy_bounds(x, y, zoom)
                    bgra = render(sources, (b.left, b.bottom, b.right, b.top), TILE_SIZE)
                    if not bgra[..., 3].any():
                        continue
                    rgba = np.moveaxis(bgra[..., [2, 1, 0, 3]], -1, 0)
                    out.write(rgba, window=Window((x - x0) * TILE_SIZE, (y - y0) * TILE_SIZE,
                                                  TILE_SIZE, TILE_SIZE))
        write_cog(tmp, dst, "uint8", 3)
    finally:
        tmp.unlink(missing_ok=True)
    return zoom
