"""Edge geometry of the road graph: from pixel chains to smooth sub-pixel centrelines.

The skeleton decides the topology (which nodes, which edges); this module decides where
each edge runs. For every edge:

1. *Stations* every ``station_m`` along its pixel chain, each with the chain's direction
   there (the chain smoothed over a few metres first, so a staircase does not tilt it).
2. A *cross-section* of the soft road field at each station (:mod:`ingest.roads.ridge`):
   the midpoint of the two road edges, and the width. Sections within a crossing road's
   reach of a junction are not used (they cut along the other road), nor are those whose
   width differs from the edge's typical width by more than ``WIDTH_SPREAD`` (a driveway or
   a car park opening one side of the road pulls its midpoint sideways).
3. *Junction nodes* move to where the approaching centrelines, extended straight, meet
   (least squares): that is where a driver sees the crossing, and it lets every approach
   arrive straight, without the kink a skeleton makes as it bends into the blob's centre.
4. A *smoothing spline* (:mod:`ingest.roads.curve`) through the sections (and the junction
   nodes, held firmly), dense-sampled, then simplified to ``simplify_m`` without sharp
   vertices. Where no section could be trusted (a bridged gap, the edge of the data), the
   skeleton's own pixel positions hold the curve, weakly.
5. A dead end's node moves onto the fitted curve's straight continuation, cut back to the
   last pixel with data (:func:`clip_to_data`): where a drive's coverage ends across a
   road the road goes on, but nothing may be drawn where nobody saw the ground.

Widths are the median section width; ``confidence`` is the mean of the field along the
final line (see :func:`confidence`).
"""

from __future__ import annotations

from dataclasses import dataclass

import networkx as nx
import numpy as np
from scipy.ndimage import gaussian_filter1d

from ingest.roads.curve import (
    arc_length,
    end_direction,
    fit_curve,
    line_intersection,
    simplify_smooth,
    smoothing_lambda,
)
from ingest.roads.ridge import RoadField, cross_sections, sample

WIDTH_SPREAD = 1.25
"""A section counts when its width is within this factor of the edge's median width."""
NODE_WEIGHT = 1e3
"""Spline weight of a junction node against one section's 1: the curve goes through it."""
SKELETON_WEIGHT = 0.05
"""Spline weight of a skeleton pixel where no section is trusted: it keeps the line where
the road is, but a few good sections nearby outvote its staircase."""
DIRECTION_SIGMA_M = 2.0
"""Smoothing of the pixel chain before its direction is read."""
APPROACH_M = 6.0
"""Length of road beyond a junction's reach whose sections give an approach's direction.
Roads curve into junctions (corner radii, a side road bending to meet the main road at a
right angle), so the line through a long stretch aims away from the crossing. Chosen by
measurement with ``bench/roads_geometry.py`` on the 8 validation images and the roads-v2
snapshot of 2026-11-24 (6 / 8 / 12 m tried): junction precision / recall 0.65 / 0.27 at 6 m,
0.58 / 0.26 at 8 m, 0.56 / 0.26 at 12 m, P@2m 0.456 / 0.454 / 0.453; roads-v1 unchanged
(0.56 / 0.30 against 0.57 / 0.30)."""
DENSE_M = 0.25
"""Spacing of the dense curve that is simplified into the output vertices."""


@dataclass(frozen=True)
class Shape:
    """An edge's geometry and measurements on the working grid."""

    coords: np.ndarray
    width_px: float | None
    """Median edge-to-edge width of the trusted sections; None when there was none."""
    confidence: float


@dataclass
class _Edge:
    chain: np.ndarray
    """Node, pixel centres, node (pixel-corner x, y), oriented from ``start``."""
    start: int
    end: int
    s: np.ndarray
    """Arc positions of the stations along ``chain``."""
    first: int
    """Index of this edge's first station in the batched arrays."""


def _stations(chain: np.ndarray, spacing: float, sigma: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(arc positions, points, unit normals) every ``spacing`` along ``chain``, strictly inside
    it; the normals come from the chain smoothed with ``sigma`` (pixels of arc)."""
    cum = arc_length(chain)
    total = float(cum[-1])
    count = int(total // spacing)
    if count < 1 or total <= 0:
        return np.empty(0), np.empty((0, 2)), np.empty((0, 2))
    s = (np.arange(count) + 0.5) * (total / count)
    pts = np.column_stack([np.interp(s, cum, chain[:, 0]), np.interp(s, cum, chain[:, 1])])
    # Smooth over arc length, not vertices: a simplified chain has few, uneven vertices.
    u = np.linspace(0.0, total, max(int(total), 2) + 1)
    even = np.column_stack([np.interp(u, cum, chain[:, 0]), np.interp(u, cum, chain[:, 1])])
    tangent = np.gradient(gaussian_filter1d(even, sigma * len(u) / total, axis=0,
                                            mode="nearest"), u, axis=0)
    tx, ty = np.interp(s, u, tangent[:, 0]), np.interp(s, u, tangent[:, 1])
    norm = np.hypot(tx, ty)
    norm[norm == 0] = 1.0
    return s, pts, np.column_stack([-ty / norm, tx / norm])


def confidence(coefficients: np.ndarray, coords: np.ndarray, spacing: float) -> float:
    """Mean of the field along a line, sampled every ``spacing`` pixels, clipped to 0..1.

    For the road model this is the mean road probability under the centreline: high where
    the network saw the road along its whole length, lower where the line crosses a gap the
    topology bridged or a stretch the threshold barely kept. For the colour classifiers the
    field is their smoothed mask, so it falls only where the line crosses what the mask
    calls background."""
    cum = arc_length(coords)
    s = np.linspace(0, cum[-1], max(2, int(cum[-1] / spacing) + 1))
    pts = np.column_stack([np.interp(s, cum, coords[:, 0]), np.interp(s, cum, coords[:, 1])])
    return float(np.clip(sample(coefficients, pts), 0.0, 1.0).mean())


def _oriented_chain(g: nx.MultiGraph, u: int, v: int, key: int, pixel_xy: np.ndarray
                    ) -> tuple[np.ndarray, int, int]:
    data = g.edges[u, v, key]
    start = data["start"]
    end = v if start == u else u
    coords = np.vstack([g.nodes[start]["xy"], pixel_xy, g.nodes[end]["xy"]])
    keep = np.r_[True, np.any(np.diff(coords, axis=0) != 0, axis=1)]
    return coords[keep], start, end


def refine_geometry(g: nx.MultiGraph, pixel_xy: dict[tuple[int, int, int], np.ndarray],
                    field: RoadField, coefficients: np.ndarray, resolution_m: float,
                    station_m: float, smooth_m: float,
                    simplify_m: float, max_turn_deg: float, max_half_width_m: float
                    ) -> tuple[dict[tuple[int, int, int], Shape], dict[int, tuple[float, float]]]:
    """Geometry of every edge of ``g`` (keys as in ``pixel_xy``: :func:`edge_key` -> the
    pixel-centre chain of each edge in its stored order) and the refined position of every
    node; ``coefficients`` are ``field.coefficients()``."""
    spacing = max(station_m / resolution_m, 0.5)
    junction = {n for n in g.nodes if g.degree(n) >= 3}
    edges: dict[tuple[int, int, int], _Edge] = {}
    points, normals = [], []
    total = 0
    for key, xy in pixel_xy.items():
        chain, start, end = _oriented_chain(g, *key, xy)
        s, pts, nv = _stations(chain, spacing, DIRECTION_SIGMA_M / resolution_m)
        edges[key] = _Edge(chain, start, end, s, total)
        points.append(pts)
        normals.append(nv)
        total += len(s)
    sections = cross_sections(coefficients, field, np.vstack([np.empty((0, 2)), *points]),
                              np.vstack([np.empty((0, 2)), *normals]),
                              max_half_width_m / resolution_m)

    # Per edge: the trusted sections (consistent width, clear of junctions).
    widths: dict[tuple[int, int, int], float | None] = {}
    trusted: dict[tuple[int, int, int], np.ndarray] = {}
    for key, e in edges.items():
        sl = slice(e.first, e.first + len(e.s))
        w = sections.widths_px[sl]
        ok = sections.ok[sl]
        median = float(np.median(w[ok])) if ok.any() else None
        if median is not None:
            ok = ok & (w <= median * WIDTH_SPREAD) & (w >= median / WIDTH_SPREAD)
        widths[key] = median
        trusted[key] = ok
    reach: dict[int, float] = {}
    for n in junction:
        incident = [wd for k in _incident(g, n) if (wd := widths.get(k)) is not None]
        reach[n] = (max(incident) if incident else 0.0) + 1.0 / resolution_m
    clear: dict[tuple[int, int, int], np.ndarray] = {}
    for key, e in edges.items():
        length = arc_length(e.chain)[-1]
        away = np.ones(len(e.s), bool)
        if e.start in junction:
            away &= e.s > reach[e.start]
        if e.end in junction:
            away &= e.s < length - reach[e.end]
        clear[key] = away
        trusted[key] &= away
        if trusted[key].any():
            sl = slice(e.first, e.first + len(e.s))
            w = sections.widths_px[sl][trusted[key]]
            widths[key] = float(np.median(w))

    nodes = {n: tuple(g.nodes[n]["xy"]) for n in g.nodes}
    for n in junction:
        nodes[n] = _junction_point(g, n, edges, sections, trusted, reach[n], resolution_m)

    lam = smoothing_lambda(smooth_m / resolution_m, spacing)
    shapes = {}
    for key, e in edges.items():
        ring = g.degree(e.start) == 2 and e.start == e.end
        coords = _fit_edge(e, sections, trusted[key], clear[key], nodes, junction, lam,
                           DENSE_M / resolution_m, ring)
        if field.valid is not None and not ring:
            coords = clip_to_data(coords, field.valid, e.start not in junction,
                                  e.end not in junction)
        if e.start not in junction:
            nodes[e.start] = tuple(coords[0])
        if e.end not in junction:
            nodes[e.end] = tuple(coords[-1])
        coords = simplify_smooth(coords, simplify_m / resolution_m, max_turn_deg)
        shapes[key] = Shape(coords, widths[key], confidence(coefficients, coords, spacing))
    return shapes, nodes


def edge_key(u: int, v: int, k: int) -> tuple[int, int, int]:
    """One name per multigraph edge whichever end it is seen from."""
    return (u, v, k) if u <= v else (v, u, k)


def _incident(g: nx.MultiGraph, n: int) -> list[tuple[int, int, int]]:
    """Keys (:func:`edge_key`) of the edges at node ``n``, a self-loop once."""
    return sorted({edge_key(u, v, k) for u, v, k in g.edges(n, keys=True)})


def _junction_point(g: nx.MultiGraph, n: int, edges: dict[tuple[int, int, int], _Edge],
                    sections, trusted: dict, reach_px: float, resolution_m: float
                    ) -> tuple[float, float]:
    """Where the approaches to junction ``n`` cross: each approach is the line through its
    trusted sections within ``APPROACH_M`` beyond the junction's reach."""
    prior = np.asarray(g.nodes[n]["xy"], float)
    pts, dirs = [], []
    approach = APPROACH_M / resolution_m
    for key in _incident(g, n):
        e = edges.get(key)
        if e is None:
            continue
        sl = slice(e.first, e.first + len(e.s))
        good = trusted[key]
        centres = sections.centres[sl][good]
        s = e.s[good]
        length = arc_length(e.chain)[-1]
        if e.start == n:
            near = centres[s <= reach_px + approach]
            if len(near) >= 3:
                pts.append(near[0])
                dirs.append(end_direction(near, approach))
        if e.end == n:
            near = centres[s >= length - reach_px - approach][::-1]
            if len(near) >= 3:
                pts.append(near[0])
                dirs.append(end_direction(near, approach))
    if len(pts) < 2:
        return float(prior[0]), float(prior[1])
    x = line_intersection(np.array(pts), np.array(dirs), prior)
    if np.hypot(*(x - prior)) > reach_px:
        return float(prior[0]), float(prior[1])
    return float(x[0]), float(x[1])


def _fit_edge(e: _Edge, sections, trusted: np.ndarray, clear: np.ndarray,
              nodes: dict[int, tuple[float, float]], junction: set[int], lam: float,
              dense_px: float, ring: bool) -> np.ndarray:
    """Dense smooth centreline of one edge, from its start node to its end node."""
    sl = slice(e.first, e.first + len(e.s))
    length = float(arc_length(e.chain)[-1])
    centres = sections.centres[sl]
    use = trusted | clear  # untrusted sections away from junctions: skeleton position, weakly
    s = e.s[use]
    xy = np.where(trusted[use, None], centres[use], _on_chain(e, s))
    w = np.where(trusted[use], 1.0, SKELETON_WEIGHT)
    if ring:
        s = np.r_[s - length, s, s + length]
        xy = np.vstack([xy, xy, xy])
        w = np.r_[w, w, w]
        out = np.linspace(0.0, length, max(int(length / dense_px), 8) + 1)
        dense = fit_curve(s, xy, w, lam, out) if len(s) else e.chain
        dense[-1] = dense[0]
        return dense
    fixed_start, fixed_end = e.start in junction, e.end in junction
    if fixed_start or not len(s):
        s, xy, w = np.r_[0.0, s], np.vstack([nodes[e.start], xy]), np.r_[NODE_WEIGHT, w]
    if fixed_end or len(s) < 2:
        s, xy = np.r_[s, length], np.vstack([xy, nodes[e.end]])
        w = np.r_[w, NODE_WEIGHT]
    out = np.linspace(s[0], s[-1], max(int((s[-1] - s[0]) / dense_px), 1) + 1)
    dense = fit_curve(s, xy, w, lam, out)
    if fixed_start:
        dense[0] = nodes[e.start]
    else:
        dense = _extend(dense, s[0], dense_px * 12, reverse=True)
    if fixed_end:
        dense[-1] = nodes[e.end]
    else:
        dense = _extend(dense, length - s[-1], dense_px * 12, reverse=False)
    return dense


def _on_data(xy: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Whether each pixel-corner (x, y) point lies on a pixel with data (off the grid: no)."""
    col, row = np.floor(xy[:, 0]).astype(np.intp), np.floor(xy[:, 1]).astype(np.intp)
    inside = (row >= 0) & (row < valid.shape[0]) & (col >= 0) & (col < valid.shape[1])
    out = np.zeros(len(xy), bool)
    out[inside] = valid[row[inside], col[inside]]
    return out


def clip_to_data(dense: np.ndarray, valid: np.ndarray, start_free: bool, end_free: bool,
                 step_px: float = 0.25) -> np.ndarray:
    """``dense`` (a finely sampled centreline) cut back at its free ends to where it first
    reaches a pixel with data (``valid``), to ``step_px``.

    Where a drive's coverage ends across a road, the mask ends there but the road does not:
    the skeleton's end, the straight continuation of a dead end and the smoothing spline all
    land up to a working pixel beyond the last pixel with data. A planner must not be sent
    where nobody has seen the ground, so the line stops at the coverage. Junction ends are
    never moved (the crossing is on data: the roads meeting there were seen)."""
    if len(dense) < 2:
        return dense
    on = _on_data(dense, valid)
    if not on.any():
        return dense
    first, last = int(np.argmax(on)), len(on) - 1 - int(np.argmax(on[::-1]))
    if not start_free:
        first = 0
    if not end_free:
        last = len(dense) - 1
    out = dense[first:last + 1]
    if first > 0:
        out = np.vstack([_boundary(dense[first], dense[first - 1], valid, step_px), out])
    if last < len(dense) - 1:
        out = np.vstack([out, _boundary(dense[last], dense[last + 1], valid, step_px)])
    keep = np.r_[True, np.any(np.diff(out, axis=0) != 0, axis=1)]
    return out[keep] if keep.sum() >= 2 else dense[first:last + 1]


def _boundary(inner: np.ndarray, outer: np.ndarray, valid: np.ndarray, step_px: float
              ) -> np.ndarray:
    """The farthest point from ``inner`` (on data) towards ``outer`` (no data) reached
    before the first no-data pixel, in steps of ``step_px``."""
    count = max(int(np.ceil(np.hypot(*(outer - inner)) / step_px)), 1)
    pts = inner + np.linspace(0.0, 1.0, count + 1)[:, None] * (outer - inner)
    on = _on_data(pts, valid)
    return pts[int(np.argmin(on)) - 1] if not on.all() else pts[-1]


def _on_chain(e: _Edge, s: np.ndarray) -> np.ndarray:
    cum = arc_length(e.chain)
    return np.column_stack([np.interp(s, cum, e.chain[:, 0]), np.interp(s, cum, e.chain[:, 1])])


def _extend(dense: np.ndarray, distance: float, reach: float, reverse: bool) -> np.ndarray:
    """``dense`` continued straight along its end tangent by ``distance`` (at its start when
    ``reverse``): a dead end is where the road stops, along the road's own line."""
    if distance <= 1e-6 or len(dense) < 2:
        return dense
    pts = dense[::-1] if not reverse else dense
    d = end_direction(pts, reach)
    tip = pts[0] - d * distance
    return np.vstack([tip, dense]) if reverse else np.vstack([dense, tip])
