"""OSRM's ``overview=simplified``: the route line thinned for the zoom that shows it whole.

Like OSRM, the tolerance follows the zoom level at which the route's bounding box fits the
screen: Douglas-Peucker (shapely's ``simplify``) in web-mercator metres with a tolerance of one
pixel at the largest zoom (at most :data:`MAX_ZOOM`) where the route spans at most
:data:`VIEWPORT_PX` pixels. The kept points are original vertices, so the line still starts
and ends exactly at the waypoints.
"""

from __future__ import annotations

import numpy as np
import shapely

from app.grid import pixel_size_m

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
    with np.errstate(invalid="ignore", divide="ignore"):
        x = np.radians(lonlat[:, 0]) * MERCATOR_R
        y = np.log(np.tan(np.pi / 4 + np.radians(lonlat[:, 1]) / 2)) * MERCATOR_R
    if not (np.isfinite(x).all() and np.isfinite(y).all()):  # off the globe: leave it be
        return lonlat
    span = float(max(np.ptp(x), np.ptp(y)))
    tolerance = PIXEL_M[fitted_zoom(span)]
    # Each vertex carries its index as Z, which simplification keeps with the vertex.
    line = shapely.linestrings(x, y, np.arange(len(x), dtype=np.float64))
    kept = shapely.get_coordinates(shapely.simplify(line, tolerance, preserve_topology=False),
                                   include_z=True)[:, 2].astype(np.int64)
    return lonlat[kept]
