"""Smooth centreline curves: spline fitting, junction points, and simplification that keeps
curves smooth.

A road's centre points (sub-pixel, but each with its own measurement noise) become one
smoothing spline per coordinate against arc length. Its stiffness is set by a wavelength in
metres (``smooth_m``): wiggles shorter than that are noise, because a road that wavers by
a few decimetres every few metres does not exist, while a bend of radius 5 m and more keeps
its shape (the spline's gain at a wavelength of 2πR is 1 / (1 + (smooth_m / 2πR)^4)).

Simplifying the dense curve with Ramer-Douglas-Peucker alone would turn a long gentle bend
into a few long chords meeting at visible kinks; :func:`simplify_smooth` also splits any
chord pair that would turn by more than ``max_turn_deg``, so a vehicle following the
vertices never turns sharper than the road.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import shapely
from scipy.interpolate import make_smoothing_spline

MIN_SPLINE_POINTS = 5
"""make_smoothing_spline needs this many points; fewer are joined straight."""


def arc_length(coords: np.ndarray) -> np.ndarray:
    """Cumulative length along a polyline, starting at 0."""
    return np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(coords, axis=0), axis=1))]


def smoothing_lambda(smooth_px: float, spacing_px: float) -> float:
    """The spline penalty whose cut-off wavelength is ``smooth_px`` for points every
    ``spacing_px`` with unit weights: the fit's gain at angular frequency w is
    1 / (1 + lam * w^4 / density), density = 1 / spacing."""
    return float((smooth_px / (2 * math.pi)) ** 4 / spacing_px)


def fit_curve(s: np.ndarray, xy: np.ndarray, weights: np.ndarray, lam: float,
              s_out: np.ndarray) -> np.ndarray:
    """Smoothing-spline fit of points ``xy`` at arc positions ``s`` (strictly increasing),
    evaluated at ``s_out`` (within [s[0], s[-1]]); few points are joined straight."""
    if len(s) < MIN_SPLINE_POINTS:
        return np.column_stack([np.interp(s_out, s, xy[:, 0]), np.interp(s_out, s, xy[:, 1])])
    spline = make_smoothing_spline(s, xy, w=weights, lam=lam)
    return np.asarray(spline(s_out))


def line_intersection(points: np.ndarray, directions: np.ndarray, prior: np.ndarray,
                      prior_weight: float = 0.05) -> np.ndarray:
    """The point closest (least squares, perpendicular distance) to lines through ``points``
    along unit ``directions``, pulled weakly towards ``prior``: where roads meet, their
    extended centrelines cross; with parallel lines the prior decides along them."""
    normals = np.column_stack([-directions[:, 1], directions[:, 0]])
    a = prior_weight * np.eye(2)
    b = prior_weight * np.asarray(prior, float)
    for p, nv in zip(points, normals, strict=True):
        outer = np.outer(nv, nv)
        a += outer
        b += outer @ p
    return np.linalg.solve(a, b)


def end_direction(xy: np.ndarray, reach: float) -> np.ndarray:
    """Unit direction of a polyline's first ``reach`` (pixels) of length, pointing from its
    start into it (principal axis of those points)."""
    s = arc_length(xy)
    pts = xy[s <= max(reach, s[1] if len(s) > 1 else 0.0)]
    if len(pts) < 2:
        pts = xy[:2]
    centred = pts - pts.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    d = vt[0]
    return d if (pts[-1] - pts[0]) @ d >= 0 else -d


def simplify_smooth(dense: np.ndarray, tolerance: float, max_turn_deg: float) -> np.ndarray:
    """Vertices of ``dense`` (a finely sampled smooth curve) within ``tolerance`` of it, with
    no vertex turning by more than ``max_turn_deg`` where the curve itself does not."""
    if len(dense) <= 2:
        return dense
    kept = np.asarray(shapely.LineString(dense).simplify(tolerance, preserve_topology=False)
                      .coords)
    # RDP keeps a subset of the input vertices: find them back by position, in order.
    index = {tuple(p): i for i, p in enumerate(dense.tolist())}
    idx = sorted({index[tuple(p)] for p in kept.tolist()} | {0, len(dense) - 1})
    step = np.diff(dense, axis=0)
    heading = np.unwrap(np.arctan2(step[:, 1], step[:, 0]))
    heading = np.r_[heading, heading[-1]]
    limit = math.radians(max_turn_deg)
    out = [idx[0]]
    for i, j in itertools.pairwise(idx):
        turn = abs(heading[j] - heading[i])
        pieces = min(math.ceil(turn / limit), j - i) if turn > limit else 1
        out.extend(np.linspace(i, j, pieces + 1).round().astype(int)[1:].tolist())
    return dense[out]
