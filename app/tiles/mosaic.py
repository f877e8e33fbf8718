"""Compose one XYZ tile from the COG sources that meet it.

Every source COG sits on the web-mercator grid, so at a native or overview zoom the tile is
an integer, block-aligned window of one pyramid level: GDAL picks that level and copies the
block, no warping. Other zooms (over-zoom, or below the smallest overview) fall back to a
resampled read of the same window. Sources are painted bottom-up through their masks, so the
newest/highest-priority source covers older ones and nodata never paints black.
"""

from __future__ import annotations

import numpy as np
from rasterio.enums import Resampling

from app.errors import InvalidParameterValueError
from app.grid import tile_bounds
from app.tiles.catalog import TileQuery, TileSource
from app.tiles.elevation import check_render, relief
from app.tiles.encode import encode
from app.tiles.placement import open_source, place
from app.tiles.readers import overview_zoom


def _to_uint8(data: np.ndarray, display_range: list[list[float]] | None) -> np.ndarray:
    if data.dtype == np.uint8:
        return data
    out = np.empty(data.shape, np.uint8)
    for i, band in enumerate(data):
        lo, hi = display_range[min(i, len(display_range) - 1)] if display_range else (0, 1)
        scaled = (band.astype(np.float32) - lo) * (255.0 / (hi - lo))
        np.clip(scaled, 0, 255, out=scaled)
        out[i] = scaled
    return out


def paint(canvas: np.ndarray, source: TileSource,
          bbox: tuple[float, float, float, float]) -> None:
    """Paint ``source`` into ``canvas`` (H x W x 4, BGRA) where the source has valid pixels."""
    ds = open_source(source)
    size_y, size_x = canvas.shape[:2]
    placed = place(ds, bbox, size_x, size_y)
    if placed is None:
        return
    window, resampling, shape = placed.window, placed.resampling, placed.shape
    y0, y1, x0, x1 = placed.y0, placed.y1, placed.x0, placed.x1
    bands = [1, 2, 3] if ds.count >= 3 else [1]
    data = ds.read(bands, window=window, out_shape=(len(bands), *shape), resampling=resampling)
    mask = ds.read_masks(1, window=window, out_shape=shape, resampling=Resampling.nearest)
    data = _to_uint8(data, source.display_range)
    target = canvas[y0:y1, x0:x1]
    pixels = np.moveaxis(data[::-1] if len(bands) == 3 else np.repeat(data, 3, axis=0), 0, -1)
    valid = mask > 0
    if valid.all():
        target[..., :3] = pixels
        target[..., 3] = 255
    elif valid.any():
        target[valid, :3] = pixels[valid]
        target[valid, 3] = 255


def render(sources: list[TileSource], bbox: tuple[float, float, float, float],
           size: int) -> np.ndarray:
    """The tile as a ``size`` x ``size`` BGRA array (transparent where nothing covers it)."""
    canvas = np.zeros((size, size, 4), np.uint8)
    for source in sources:
        paint(canvas, source, bbox)
    return canvas


def compose_tile(query: TileQuery, z: int, x: int, y: int, fmt: str, size: int = 256,
                 draw: str | None = None) -> bytes:
    """Tile z/x/y of a layer, encoded as served: from the layer overview at the zooms it
    covers, else from the sources meeting the tile. The one path the tile endpoint and the
    offline package both take, so a packaged tile is the served tile byte for byte.
    An elevation layer is drawn as ``draw`` (:data:`app.tiles.elevation.RENDERS`)."""
    sources = query.sources
    if sources and query.overview_uri and z <= overview_zoom(query.overview_uri):
        sources = [TileSource(query.overview_uri, None)]
    draw = check_render(draw, query.kind)
    if draw is None:
        return encode(render(sources, tile_bounds(z, x, y), size), fmt)
    if draw == "terrarium" and fmt != "png":
        raise InvalidParameterValueError(
            f"Terrarium tiles are lossless PNG (.png), not .{fmt}: lossy pixels are wrong heights")
    return encode(relief(sources, tile_bounds(z, x, y), size, draw), fmt)
