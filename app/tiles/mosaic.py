"""Compose one XYZ tile from the COG sources that meet it.

Every source COG sits on the web-mercator grid, so at a native or overview zoom the tile is
an integer, block-aligned window of one pyramid level: GDAL picks that level and copies the
block, no warping. Other zooms (over-zoom, or below the smallest overview) fall back to a
resampled read of the same window. Sources are painted bottom-up through their masks, so the
newest/highest-priority source covers older ones and nodata never paints black.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from rasterio.enums import Resampling
from rasterio.errors import RasterioIOError
from rasterio.windows import Window

from app.errors import RasterSourceMissingError
from app.grid import tile_bounds
from app.tiles.catalog import TileQuery, TileSource
from app.tiles.encode import encode
from app.tiles.readers import open_dataset, overview_zoom

log = logging.getLogger(__name__)


def _is_exact_level(ratio: float) -> bool:
    """True when ``ratio`` source pixels per tile pixel is 1, 2, 4, ... (a pyramid level)."""
    if ratio < 1 - 1e-6:
        return False
    level = math.log2(ratio)
    return abs(level - round(level)) < 1e-6


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
    try:
        ds = open_dataset(source.uri)
    except RasterioIOError as exc:
        # A blank tile would hide the problem from everyone: the client gets an error, the
        # operator the file that is missing.
        log.error("raster source %s cannot be read: %s", source.uri, exc)
        raise RasterSourceMissingError("a source file of this layer is missing from the "
                                       "raster store (the server log names it)") from None
    size_y, size_x = canvas.shape[:2]
    left, top = ds.transform.c, ds.transform.f
    res_x, res_y = ds.transform.a, -ds.transform.e
    col, row = (bbox[0] - left) / res_x, (top - bbox[3]) / res_y
    width, height = (bbox[2] - bbox[0]) / res_x, (bbox[3] - bbox[1]) / res_y
    c0, c1 = max(col, 0.0), min(col + width, ds.width)
    r0, r1 = max(row, 0.0), min(row + height, ds.height)
    if c1 <= c0 or r1 <= r0:
        return
    x0, x1 = round((c0 - col) * size_x / width), round((c1 - col) * size_x / width)
    y0, y1 = round((r0 - row) * size_y / height), round((r1 - row) * size_y / height)
    if x1 <= x0 or y1 <= y0:
        return
    window = Window(c0, r0, c1 - c0, r1 - r0)
    exact = _is_exact_level(width / size_x)
    resampling = Resampling.nearest if exact else Resampling.bilinear
    bands = [1, 2, 3] if ds.count >= 3 else [1]
    shape = (y1 - y0, x1 - x0)
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


def compose_tile(query: TileQuery, z: int, x: int, y: int, fmt: str, size: int = 256) -> bytes:
    """Tile z/x/y of a layer, encoded as served: from the layer overview at the zooms it
    covers, else from the sources meeting the tile. The one path the tile endpoint and the
    offline package both take, so a packaged tile is the served tile byte for byte."""
    sources = query.sources
    if sources and query.overview_uri and z <= overview_zoom(query.overview_uri):
        sources = [TileSource(query.overview_uri, None)]
    return encode(render(sources, tile_bounds(z, x, y), size), fmt)
