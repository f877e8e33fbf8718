"""OSRM's ``overview=simplified``: the route line thinned for the zoom that shows it whole.

Like OSRM, the tolerance follows the zoom level at which the route's bounding box fits the
screen: Douglas-Peucker in web-mercator metres with a tolerance of one pixel at the largest
zoom (at most :data:`MAX_ZOOM`) where the route spans at most :data:`VIEWPORT_PX` pixels. The
kept points are original vertices, so the line still starts and ends exactly at the waypoints.

Douglas-Peucker is GEOS's (``shapely.simplify``) step for step, compiled
(:mod:`app.routing.native`): through shapely it cost ~70 us a city route, mostly building the
line and reading it back.
"""

from __future__ import annotations

import numpy as np

from app.grid import pixel_size_m
from app.routing.native import kernel

VIEWPORT_PX = 1024
MAX_ZOOM = 18  # OSRM's highest simplification level
MERCATOR_R = 6_378_137.0  # EPSG:3857's sphere
PIXEL_M = tuple(pixel_size_m(zoom) for zoom in range(MAX_ZOOM + 1))  # read once, not per route


def fitted_zoom(span_m: float) -> int:
    """The largest zoom (<= :data:`MAX_ZOOM`) where ``span_m`` mercator metres fit the viewport."""
    for zoom in range(MAX_ZOOM, -1, -1):
        if span_m <= VIEWPORT_PX * PIXEL_M[zoom]:
            return zoom
    return 0


def simplify(lonlat: np.ndarray) -> np.ndarray:
    """The route line (lon/lat rows) with the vertices a map at the fitted zoom would not
    show removed."""
    if len(lonlat) <= 2:
        return lonlat
    x, y, span = _mercator(lonlat)
    if not span >= 0.0:  # off the globe: leave it be
        return lonlat
    return lonlat[_douglas_peucker(x, y, PIXEL_M[fitted_zoom(span)])]


@kernel("Tuple((f8[:], f8[:], f8))(f8[:, :])")
def _mercator(lonlat: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Web-mercator x and y of ``lonlat`` and the larger of their extents (NaN when a point has
    no mercator position: beyond the poles, or not a number)."""
    n = len(lonlat)
    x, y = np.empty(n), np.empty(n)
    for i in range(n):
        x[i] = np.radians(lonlat[i, 0]) * MERCATOR_R
        y[i] = np.log(np.tan(np.pi / 4 + np.radians(lonlat[i, 1]) / 2)) * MERCATOR_R
        if not (np.isfinite(x[i]) and np.isfinite(y[i])):
            return x, y, np.nan
    return x, y, max(x.max() - x.min(), y.max() - y.min())


@kernel("i8[:](f8[:], f8[:], f8)")
def _douglas_peucker(x: np.ndarray, y: np.ndarray, tolerance: float) -> np.ndarray:
    """Indices of the vertices Douglas-Peucker keeps at ``tolerance``: GEOS's
    ``DouglasPeuckerLineSimplifier`` (the first vertex farthest from a section's chord splits
    it, unless it is within the tolerance; distances to the chord as a segment), without
    recursion."""
    n = len(x)
    keep = np.ones(n, np.bool_)
    stack = np.empty((n, 2), np.int64)
    stack[0, 0], stack[0, 1] = 0, n - 1
    top = 1
    while top:
        top -= 1
        i, j = stack[top, 0], stack[top, 1]
        if i + 1 >= j:
            continue
        ax, ay, bx, by = x[i], y[i], x[j], y[j]
        len2 = (bx - ax) ** 2 + (by - ay) ** 2
        far, far_k = -1.0, i
        for k in range(i + 1, j):
            px, py = x[k], y[k]
            r = ((px - ax) * (bx - ax) + (py - ay) * (by - ay)) / len2 if len2 > 0.0 else 0.0
            if len2 == 0.0 or r <= 0.0:
                d = np.sqrt((px - ax) ** 2 + (py - ay) ** 2)
            elif r >= 1.0:
                d = np.sqrt((px - bx) ** 2 + (py - by) ** 2)
            else:
                d = abs(((ay - py) * (bx - ax) - (ax - px) * (by - ay)) / len2) * np.sqrt(len2)
            if d > far:
                far, far_k = d, k
        if far <= tolerance:
            keep[i + 1:j] = False
        else:
            stack[top, 0], stack[top, 1] = far_k, j
            stack[top + 1, 0], stack[top + 1, 1] = i, far_k
            top += 2
    return np.flatnonzero(keep)
