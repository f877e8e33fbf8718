"""Footprint of a written COG: the area where it has valid pixels, in EPSG:3857; and where
sources are: which of them form one connected area, and a place in words.

Tiles ask PostGIS which footprints meet them, so the footprint must never be *smaller* than
the data (a tile would miss a source); it may be slightly larger (one extra source read).
It is traced on a coarse overview of the mask and grown by one coarse pixel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
import shapely
from pyproj import Geod
from rasterio.features import shapes
from rasterio.io import DatasetReader
from rasterio.transform import Affine
from shapely.geometry import MultiPolygon, Polygon, shape
from shapely.geometry.base import BaseGeometry
from shapely.ops import unary_union

#: Longest side of the mask the footprint is traced on.
TRACE_PX = 1024


def footprint_3857(ds: DatasetReader) -> MultiPolygon | None:
    """The valid-data outline of an open EPSG:3857 raster, or None if it has no valid pixel."""
    scale = max(1, math.ceil(max(ds.width, ds.height) / TRACE_PX))
    out_w, out_h = math.ceil(ds.width / scale), math.ceil(ds.height / scale)
    mask = ds.dataset_mask(out_shape=(out_h, out_w))
    transform = ds.transform @ Affine.scale(ds.width / out_w, ds.height / out_h)
    valid = cv2.dilate((mask > 0).astype(np.uint8), np.ones((3, 3), np.uint8))
    if not valid.any():
        return None
    polygons = [shape(geom) for geom, value in shapes(valid, mask=valid > 0,
                                                      transform=transform) if value]
    pixel = abs(transform.a)
    outline = unary_union(polygons).simplify(pixel / 2)
    parts = [outline] if isinstance(outline, Polygon) else list(outline.geoms)
    return MultiPolygon([p for p in parts if isinstance(p, Polygon) and not p.is_empty])


def connected_areas(geoms: Sequence[BaseGeometry]) -> list[int]:
    """For each geometry, the number of the connected area it belongs to (geometries that
    overlap or touch, directly or through others, share one), numbered in the order of each
    area's first geometry: what a layer's sources cover as separate places."""
    union = shapely.union_all(list(geoms))
    parts = list(getattr(union, "geoms", [union]))
    member = [next(i for i, part in enumerate(parts) if part.intersects(g)) for g in geoms]
    order = {area: n for n, area in enumerate(dict.fromkeys(member))}
    return [order[m] for m in member]


def where(bounds_4326: Sequence[float]) -> str:
    """A lon/lat box in words: its centre (lon,lat, as every command takes points) and its
    ground size, so a wrong --crs shows at once (a survey of Boston said to be in Italy)."""
    west, south, east, north = bounds_4326
    lon, lat = (west + east) / 2, (south + north) / 2
    geod = Geod(ellps="WGS84")
    width = geod.inv(west, lat, east, lat)[2]
    height = geod.inv(lon, south, lon, north)[2]
    size = (f"{width:,.0f} x {height:,.0f} m" if max(width, height) < 10_000
            else f"{width / 1000:,.1f} x {height / 1000:,.1f} km")
    return f"centre {lon:.5f},{lat:.5f}, {size}"
