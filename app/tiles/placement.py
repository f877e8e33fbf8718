"""Where a source COG meets a tile, and opening it: what the colour mosaic and the height
grids of elevation layers (:mod:`app.tiles.elevation`) share.

Every source COG sits on the web-mercator grid, so at a native or overview zoom the tile is
an integer, block-aligned window of one pyramid level (read as is); other zooms are a
resampled read of the same window.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from rasterio.enums import Resampling
from rasterio.errors import RasterioIOError
from rasterio.io import DatasetReader
from rasterio.windows import Window

from app.errors import RasterSourceMissingError
from app.tiles.catalog import TileSource
from app.tiles.readers import open_dataset

log = logging.getLogger(__name__)


def _is_exact_level(ratio: float) -> bool:
    """True when ``ratio`` source pixels per tile pixel is 1, 2, 4, ... (a pyramid level)."""
    if ratio < 1 - 1e-6:
        return False
    level = math.log2(ratio)
    return abs(level - round(level)) < 1e-6


@dataclass(frozen=True)
class Placement:
    """Where a source meets a tile: the source window to read, the canvas rectangle it fills
    (rows ``y0:y1``, columns ``x0:x1``), and whether it is a pyramid level read as is."""

    window: Window
    y0: int
    y1: int
    x0: int
    x1: int
    exact: bool

    @property
    def shape(self) -> tuple[int, int]:
        """The canvas rectangle's rows and columns."""
        return self.y1 - self.y0, self.x1 - self.x0

    @property
    def resampling(self) -> Resampling:
        """Nearest on a pyramid level (a plain copy), bilinear otherwise."""
        return Resampling.nearest if self.exact else Resampling.bilinear


def open_source(source: TileSource) -> DatasetReader:
    """The source's open COG; a missing file is a 500 for the client and a log line naming
    it for the operator (a blank tile would hide the problem from everyone)."""
    try:
        return open_dataset(source.uri)
    except RasterioIOError as exc:
        log.error("raster source %s cannot be read: %s", source.uri, exc)
        raise RasterSourceMissingError("a source file of this layer is missing from the "
                                       "raster store (the server log names it)") from None


def place(ds: DatasetReader, bbox: tuple[float, float, float, float], size_x: int,
          size_y: int) -> Placement | None:
    """Where ``ds`` meets a ``size_x`` x ``size_y`` canvas over ``bbox`` (None: nowhere)."""
    left, top = ds.transform.c, ds.transform.f
    res_x, res_y = ds.transform.a, -ds.transform.e
    col, row = (bbox[0] - left) / res_x, (top - bbox[3]) / res_y
    width, height = (bbox[2] - bbox[0]) / res_x, (bbox[3] - bbox[1]) / res_y
    c0, c1 = max(col, 0.0), min(col + width, ds.width)
    r0, r1 = max(row, 0.0), min(row + height, ds.height)
    if c1 <= c0 or r1 <= r0:
        return None
    x0, x1 = round((c0 - col) * size_x / width), round((c1 - col) * size_x / width)
    y0, y1 = round((r0 - row) * size_y / height), round((r1 - row) * size_y / height)
    if x1 <= x0 or y1 <= y0:
        return None
    return Placement(Window(c0, r0, c1 - c0, r1 - r0), y0, y1, x0, x1,
                     _is_exact_level(width / size_x))
