"""Tiles of elevation layers: heights composed on a tile's grid, drawn as relief.

An elevation layer's sources are float32 heights (nodata masked), painted in the same order
as any layer's (newer or higher-priority sources on top). A tile is drawn from a height grid
one pixel wider on every side than the tile, so slope and hillshade have their 3x3 window at
the tile's edges and neighbouring tiles join without a seam.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from rasterio.enums import Resampling

from app.errors import InvalidParameterValueError
from app.grid import Bounds
from app.terrain.relief import (
    grey_shade,
    hillshade,
    slope_colours,
    slope_degrees,
    slope_legend,
    terrarium_encode,
)
from app.tiles.catalog import TileSource
from app.tiles.placement import open_source, place

#: What ``?render=`` may ask of an elevation layer; the first is a plain tile's.
RENDERS = ("hillshade", "slope", "terrarium")
EARTH_RADIUS_M = 6378137.0  # web mercator's sphere


def check_render(render: str | None, kind: str) -> str | None:
    """The render a tile request asks for: 400 for an unknown one, or one asked of a layer
    that holds no heights."""
    if render is None:
        return RENDERS[0] if kind == "elevation" else None
    if kind != "elevation":
        raise InvalidParameterValueError(
            f"render={render[:20]} is for elevation layers; this is a {kind} layer")
    if render not in RENDERS:
        raise InvalidParameterValueError(f"render must be one of {', '.join(RENDERS)}, "
                                         f"not {render[:20]!r}")
    return render


def relief_renders(tiles: str) -> dict[str, Any]:
    """What an elevation layer's JSON says of its tiles: each render's URL template (the
    layer's versioned ``tiles``), and the slope ramp's legend."""
    glue = "&" if "?" in tiles else "?"
    return {name: {"tiles": f"{tiles}{glue}render={name}"} for name in RENDERS} | {
        "slope_legend": slope_legend(), "terrarium_encoding": "terrarium"}


def read_heights(sources: list[TileSource], bbox: Bounds, width: int,
                 height: int) -> np.ndarray:
    """Heights (float32, NaN where no source has data) on a ``width`` x ``height`` grid over
    ``bbox`` (EPSG:3857), sources painted bottom-up through their masks."""
    out = np.full((height, width), np.nan, np.float32)
    for source in sources:
        ds = open_source(source)
        placed = place(ds, bbox, width, height)
        if placed is None:
            continue
        data = ds.read(1, window=placed.window, out_shape=placed.shape,
                       resampling=placed.resampling, out_dtype=np.float32)
        valid = ds.read_masks(1, window=placed.window, out_shape=placed.shape,
                              resampling=Resampling.nearest) > 0
        target = out[placed.y0:placed.y1, placed.x0:placed.x1]
        target[valid] = data[valid]
    return out


def ground_pixel(bbox: Bounds, rows: int) -> np.ndarray:
    """Ground size of a pixel per row over ``bbox``: mercator pixels shrink by
    cos(latitude) on the ground, each row at its own latitude."""
    res = (bbox[3] - bbox[1]) / rows
    y = bbox[3] - (np.arange(rows) + 0.5) * res
    return res * np.cos(2 * np.arctan(np.exp(y / EARTH_RADIUS_M)) - math.pi / 2)


def padded_heights(sources: list[TileSource], bbox: Bounds, size: int) -> np.ndarray:
    """Heights on the tile's grid plus one pixel all round (the 3x3 windows of its edges)."""
    pad = (bbox[2] - bbox[0]) / size
    return read_heights(sources, (bbox[0] - pad, bbox[1] - pad, bbox[2] + pad, bbox[3] + pad),
                        size + 2, size + 2)


def slope_grid(sources: list[TileSource], bbox: Bounds, size: int) -> np.ndarray:
    """Slope in degrees on a tile's grid: what the slope tile colours, and the numbers the
    checks against ``gdaldem slope`` compare."""
    return slope_degrees(padded_heights(sources, bbox, size), ground_pixel(bbox, size))


def relief(sources: list[TileSource], bbox: Bounds, size: int, render: str) -> np.ndarray:
    """The tile over ``bbox`` as a ``size`` x ``size`` BGRA image of ``render``."""
    if render == "terrarium":
        return terrarium_encode(read_heights(sources, bbox, size, size))
    if render == "slope":
        return slope_colours(slope_grid(sources, bbox, size))
    return grey_shade(hillshade(padded_heights(sources, bbox, size), ground_pixel(bbox, size)))
