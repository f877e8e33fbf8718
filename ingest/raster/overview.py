"""Layer-level overview: one small COG of the whole layer for low zooms.

Without it, a low-zoom tile over a city-wide survey would open every zone COG that meets it.
The overview is the layer rendered at ``maxzoom - OVERVIEW_DEPTH`` (coarser if the layer is
spread out, so it never exceeds ``MAX_TILES_PER_SIDE`` tiles a side) by the *same*
composition code that serves tiles (:func:`app.tiles.mosaic.render`), one 256 px tile at a
time into a temporary tiled GeoTIFF, then written as a COG with its own overviews. Tiles at
or below its zoom read only this file; finer tiles read the sources.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rasterio.io import DatasetWriter
from rasterio.windows import Window

from app.grid import TILE_SIZE, Bounds, covering_block, pixel_size_m, tile_bounds
from app.tiles.catalog import TileSource
from app.tiles.elevation import read_heights
from app.tiles.mosaic import render
from ingest.raster.cog import write_staged_cog
from ingest.raster.sources import HEIGHT_NODATA

OVERVIEW_DEPTH = 5
MAX_TILES_PER_SIDE = 32


def overview_zoom(bounds_3857: Bounds, maxzoom: int) -> int:
    """Finest zoom <= maxzoom - OVERVIEW_DEPTH at which the layer spans few enough tiles."""
    span = max(bounds_3857[2] - bounds_3857[0], bounds_3857[3] - bounds_3857[1])
    zoom = max(0, maxzoom - OVERVIEW_DEPTH)
    while zoom > 0 and span / (pixel_size_m(zoom) * TILE_SIZE) > MAX_TILES_PER_SIDE - 1:
        zoom -= 1
    return zoom


def _colour_tile(sources: list[TileSource], bbox: Bounds) -> np.ndarray:
    bgra = render(sources, bbox, TILE_SIZE)
    return np.moveaxis(bgra[..., [2, 1, 0, 3]], -1, 0)


def _height_tile(sources: list[TileSource], bbox: Bounds) -> np.ndarray:
    heights = read_heights(sources, bbox, TILE_SIZE, TILE_SIZE)
    return np.where(np.isfinite(heights), heights, HEIGHT_NODATA)[None].astype(np.float32)


def build_overview(sources: list[TileSource], bounds_3857: Bounds, maxzoom: int,
                   dst: Path, heights: bool = False) -> int:
    """Render the layer into ``dst`` (COG, 8-bit RGB + mask; for an elevation layer, float32
    heights + mask, which its relief tiles are drawn from); return the overview zoom."""
    zoom = overview_zoom(bounds_3857, maxzoom)
    block = covering_block(bounds_3857, zoom)
    draw = _height_tile if heights else _colour_tile

    def paint(out: DatasetWriter) -> None:
        for x, y in block.tiles():
            bands = draw(sources, tile_bounds(zoom, x, y))
            if not (bands[-1] != (HEIGHT_NODATA if heights else 0)).any():
                continue  # sparse: empty tiles are never written
            out.write(bands, window=Window((x - block.col0) * TILE_SIZE,
                                           (y - block.row0) * TILE_SIZE, TILE_SIZE, TILE_SIZE))

    if heights:
        write_staged_cog(dst, block, 1, "float32", paint, nodata=HEIGHT_NODATA)
    else:
        write_staged_cog(dst, block, 3, "uint8", paint)
    return zoom
