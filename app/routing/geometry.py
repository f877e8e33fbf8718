"""Pure line geometry for routes: partial segments, bearings, a local metric frame.

Fractions along a segment are metric (proportional to ground distance), matching the snap
fraction PostGIS computes in the local UTM zone, so a route cut at a snapped point costs
exactly ``fraction * segment cost``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pyproj import Transformer

from app.routing.native import kernel

EARTH_RADIUS_M = 6_371_008.8


def vertex_fractions(coords: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Fraction of its segment's length at each vertex of a flat, offset-indexed coord array.

    Uses an equirectangular approximation per edge (exact enough below a few km per edge).
    """
    lon, lat = np.radians(coords[:, 0]), np.radians(coords[:, 1])
    dx = np.diff(lon) * np.cos((lat[1:] + lat[:-1]) / 2)
    step = np.hypot(dx, np.diff(lat))
    # Steps that cross from one segment to the next do not count.
    step[offsets[1:-1] - 1] = 0.0
    cum = np.concatenate([[0.0], np.cumsum(step)])
    start = np.repeat(cum[offsets[:-1]], np.diff(offsets))
    total = np.repeat(cum[offsets[1:] - 1] - cum[offsets[:-1]], np.diff(offsets))
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(total > 0, (cum - start) / total, 0.0)
    # Every segment ends at 1, including zero-length ones (whose other vertices sit at 0).
    frac[offsets[1:] - 1] = 1.0
    return frac


def point_at(coords: np.ndarray, fracs: np.ndarray, f: float) -> tuple[float, float]:
    """The point at metric fraction ``f`` of a line (``np.interp`` of each axis, compiled:
    every route places its ends several times, at ~5 us a call through numpy)."""
    return _interpolated(coords, fracs, float(f))


@kernel("UniTuple(f8, 2)(f8[:, :], f8[:], f8)")
def _interpolated(coords: np.ndarray, fracs: np.ndarray, f: float) -> tuple[float, float]:
    """(lon, lat) at ``f``: each axis interpolated over the vertex fractions."""
    return np.interp(f, fracs, coords[:, 0]), np.interp(f, fracs, coords[:, 1])


def cut(coords: np.ndarray, fracs: np.ndarray, f_from: float, f_to: float) -> list[list[float]]:
    """The part of a line between two fractions, in travel order (reversed if f_from > f_to)."""
    return cut_with_fractions(coords, fracs, f_from, f_to)[0].tolist()


def cut_with_fractions(coords: np.ndarray, fracs: np.ndarray, f_from: float, f_to: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cut` as an array, plus the fraction along the line of each returned point (travel
    order), which prices each coordinate pair of a route exactly (fractions are metric)."""
    lo, hi = sorted((f_from, f_to))
    if lo == 0.0 and hi == 1.0:  # a whole segment: most pieces of a route
        pts, fr = coords, fracs
    else:
        keep = (fracs > lo) & (fracs < hi)
        pts = np.concatenate([[point_at(coords, fracs, lo)], coords[keep],
                              [point_at(coords, fracs, hi)]])
        fr = np.concatenate([[lo], fracs[keep], [hi]])
    return (pts, fr) if f_from <= f_to else (pts[::-1], fr[::-1])


def bearing(a: list[float] | tuple[float, float], b: list[float] | tuple[float, float]) -> float:
    """Initial compass bearing from a to b (lon/lat degrees), 0..360."""
    lon1, lat1, lon2, lat2 = map(math.radians, (a[0], a[1], b[0], b[1]))
    y = math.sin(lon2 - lon1) * math.cos(lat2)
    x = (math.cos(lat1) * math.sin(lat2)
         - math.sin(lat1) * math.cos(lat2) * math.cos(lon2 - lon1))
    return (math.degrees(math.atan2(y, x)) + 360.0) % 360.0


def bearing_at(coords: np.ndarray, fracs: np.ndarray, f: float) -> float:
    """Compass bearing of a line, along its geometry, at metric fraction ``f`` (the edge holding
    ``f``; past zero-length edges to the next real one)."""
    k = int(np.clip(np.searchsorted(fracs, f, side="right") - 1, 0, len(coords) - 2))
    ahead = np.flatnonzero(fracs[k + 1:] > fracs[k])
    j = k + 1 + int(ahead[0]) if len(ahead) else len(coords) - 1
    return bearing(coords[k], coords[j])


def side_of(a: Sequence[float], heading_deg: float, p: Sequence[float]) -> float:
    """Which side of a line through ``a`` with compass ``heading_deg`` the point ``p`` lies:
    positive right, negative left, zero on it (metres, locally flat)."""
    dx = (p[0] - a[0]) * math.cos(math.radians(a[1]))
    dy = p[1] - a[1]
    h = math.radians(heading_deg)
    return (dx * math.cos(h) - dy * math.sin(h)) * EARTH_RADIUS_M * math.pi / 180


def bearings(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`bearing` for arrays of (lon, lat) rows."""
    lon1, lat1, lon2, lat2 = (np.radians(v) for v in (a[:, 0], a[:, 1], b[:, 0], b[:, 1]))
    y = np.sin(lon2 - lon1) * np.cos(lat2)
    x = np.cos(lat1) * np.sin(lat2) - np.sin(lat1) * np.cos(lat2) * np.cos(lon2 - lon1)
    return (np.degrees(np.arctan2(y, x)) + 360.0) % 360.0


def haversine_m(a: tuple[float, float], b: tuple[float, float]) -> float:
    """Great-circle distance in metres: accurate enough for snap and waypoint spacing, and needs no
    projection."""
    lon1, lat1, lon2, lat2 = map(math.radians, (a[0], a[1], b[0], b[1]))
    h = (math.sin((lat2 - lat1) / 2) ** 2
         + math.cos(lat1) * math.cos(lat2) * math.sin((lon2 - lon1) / 2) ** 2)
    return 2 * EARTH_RADIUS_M * math.asin(math.sqrt(h))


def local_frame(lon0: float, lat0: float) -> Transformer:
    """lon/lat -> metres east/north of (lon0, lat0): an azimuthal equidistant projection.

    A vehicle tracker wants a flat frame anchored at the mission start; aeqd keeps distances
    from the origin exact and distortion below 1e-4 within ~60 km, like a local ENU plane.
    """
    return Transformer.from_crs(
        "EPSG:4326",
        f"+proj=aeqd +lat_0={lat0} +lon_0={lon0} +x_0=0 +y_0=0 +ellps=WGS84 +units=m",
        always_xy=True,
    )
