"""OSRM's ``overview=simplified``: the route line thinned for the zoom that shows it whole.

Like OSRM, the tolerance follows the zoom level at which the route's bounding box fits the
screen: Douglas-Peucker (shapely's ``simplify``) in web-mercator metres with a tolerance of one
pixel at the largest zoom (at most :data:`MAX_ZOOM`) where the route spans at most
:data:`VIEWPORT_PX` pixels. The kept points are original vertices, so the line still starts
and ends exactly at the waypoints.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import shapely
from pyproj import Transformer

from app.grid import pixel_size_m

VIEWPORT_PX = 1024
MAX_ZOOM = 18  # OSRM's highest simplification level


@lru_cache(maxsize=1)
def _to_mercator() -> Transformer:
    return Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)


def fitted_zoom(span_m: float) -> int:
    """The largest zoom (<= :data:`MAX_ZOOM`) where ``span_m`` mercator metres fit the viewport."""
    for zoom in range(MAX_ZOOM, -1, -1):
        if span_m <= VIEWPORT_PX * pixel_size_m(zoom):
            return zoom
    return 0


def simplify(coords: list[list[float]]) -> list[list[float]]:
    """The route line with the vertices a map at the fitted zoom would not show removed."""
    if len(coords) <= 2:
        return coords
    lonlat = np.asarray(coords, dtype=np.float64)
    x, y = _to_mercator().transform(lonlat[:, 0], lonlat[:, 1])
    xy = np.column_stack([x, y])
    if not np.isfinite(xy).all():  # a network with coordinates off the globe: leave it be
        return coords
    span = float((xy.max(axis=0) - xy.min(axis=0)).max())
    tolerance = pixel_size_m(fitted_zoom(span))
    kept = shapely.get_coordinates(
        shapely.simplify(shapely.linestrings(xy), tolerance, preserve_topology=False))
    out, j = [], 0
    for point in kept:  # the kept vertices, in order, are a subsequence of the input
        while not (xy[j, 0] == point[0] and xy[j, 1] == point[1]):
            j += 1
        out.append(coords[j])
        j += 1
    return out
