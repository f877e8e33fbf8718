"""A leg as runs: each driven segment piece with its coordinates and what driving it costs.

Built once per leg and shared by everything that shapes the answer (overview geometry,
annotations, steps, the per-leg ``segments`` list), so no part re-cuts a segment or re-prices a
coordinate pair.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from app.routing.engine import Leg, Piece
from app.routing.geometry import bearing, cut_with_fractions, point_at
from app.routing.graph import RoadGraph
from app.routing.native import kernel
from app.routing.snap import Snap

# Vertex ids for coordinates that are not network nodes (OSRM's annotation.nodes gives an id
# to every coordinate): -(segment_id * VERTEX_BASE + vertex index), stable while the segment's
# geometry is, and never equal to a node id (those are positive).
VERTEX_BASE = 1 << 20


@dataclass(frozen=True)
class Run:
    """One piece of a segment, in driving order."""

    piece: Piece
    segment_id: int
    coords: np.ndarray  # (k, 2) lon/lat in driving order (a view of the graph's where whole)
    fracs: np.ndarray  # fraction along the segment of each coordinate
    length_m: float  # of the whole segment
    speed_ms: float
    b_out: float  # bearing leaving the first coordinate
    b_in: float  # bearing reaching the last
    distance: float  # metres driven
    duration: float  # seconds at the segment's effective speed

    @property
    def pair_m(self) -> np.ndarray:
        """Metres of each consecutive coordinate pair (fractions are metric)."""
        return np.abs(np.diff(self.fracs)) * self.length_m

    @property
    def forward(self) -> bool:
        """Driven along the segment's geometry."""
        return self.piece.f_to >= self.piece.f_from

    @property
    def starts_at_node(self) -> bool:
        """The run begins at a segment end (not at a snapped point)."""
        return self.piece.f_from in (0.0, 1.0)


@dataclass(frozen=True)
class Trace:
    """A leg's driven pieces (zero-length ones dropped) as per-piece arrays, its coordinates
    (start point first, joints not repeated) and, built only when steps, annotations or
    node ids need them, its :class:`Run` objects."""

    leg: Leg
    graph: RoadGraph
    rows: np.ndarray  # segment row of each piece
    f_from: np.ndarray  # ... and the fractions it is driven from and to
    f_to: np.ndarray
    segment_ids: np.ndarray
    forward: np.ndarray
    distance: np.ndarray  # metres per piece
    duration: np.ndarray  # seconds per piece
    coords: np.ndarray  # (n, 2) lon/lat
    starts: np.ndarray  # index in coords of each piece's first coordinate, then of the last
    start: list[float]
    end: list[float]

    @cached_property
    def runs(self) -> list[Run]:
        """The pieces as runs (coordinates and bearings of each)."""
        return runs_of(self.graph, self.rows, self.f_from, self.f_to)

    @cached_property
    def ends(self) -> Ends:
        """Each piece's first coordinate and end bearings (what steps need of the runs)."""
        return ends_of(self.graph, self.rows, self.f_from, self.f_to)


def location(graph: RoadGraph, snap: Snap) -> list[float]:
    """Where a snapped point lies on its segment (lon, lat)."""
    row = graph.row_of(snap.segment_id)
    assert row is not None  # the route was planned on this graph, so it holds the snaps
    coords, fracs = graph.line(row)
    return list(point_at(coords, fracs, snap.fraction))


@dataclass(frozen=True)
class Ends:
    """Each piece's first coordinate (its own segment's vertex, or the cut point) and its
    bearings leaving that coordinate and reaching its last, in driving order, as lists: what
    steps read at every joint, found for all pieces at once (whole segments take their
    precomputed end bearings; only cut pieces, at most the leg's first and last, are cut)."""

    first: list[list[float]]
    b_out: list[float]
    b_in: list[float]


def ends_of(graph: RoadGraph, rows: np.ndarray, f_from: np.ndarray, f_to: np.ndarray
            ) -> Ends:
    """The :class:`Ends` of the pieces (segment ``rows`` driven from ``f_from`` to ``f_to``)."""
    start, end = graph.bearing_start[rows], graph.bearing_end[rows]
    forward = f_to >= f_from
    offsets, coords = graph.segs.offsets, graph.segs.coords
    first = coords[np.where(forward, offsets[rows], offsets[rows + 1] - 1)].tolist()
    b_out = np.where(forward, start, (end + 180.0) % 360.0).tolist()
    b_in = np.where(forward, end, (start + 180.0) % 360.0).tolist()
    whole = (np.minimum(f_from, f_to) == 0.0) & (np.maximum(f_from, f_to) == 1.0)
    for k in np.flatnonzero(~whole).tolist():
        line, line_fracs = graph.line(int(rows[k]))
        cut = cut_with_fractions(line, line_fracs, float(f_from[k]), float(f_to[k]))[0]
        first[k] = cut[0].tolist()
        b_out[k] = bearing(cut[0], cut[1])
        b_in[k] = bearing(cut[-2], cut[-1])
    return Ends(first, b_out, b_in)


def runs_of(graph: RoadGraph, rows: np.ndarray, f_from: np.ndarray, f_to: np.ndarray
            ) -> list[Run]:
    """The runs of the pieces (segment ``rows`` driven from ``f_from`` to ``f_to``):
    coordinates cut at their fractions, bearings at their ends (:func:`ends_of`). Per-piece
    numbers are read for all pieces at once (a city route has ~100)."""
    if not len(rows):
        return []
    ends = ends_of(graph, rows, f_from, f_to)
    lengths = graph.segs.length_m[rows]
    speeds = graph.speed_kph[rows] / 3.6
    distances = np.abs(f_to - f_from) * lengths
    runs = []
    for k, (row, a, b, sid, length, speed, distance, duration) in enumerate(zip(
            rows.tolist(), f_from.tolist(), f_to.tolist(), graph.segs.ids[rows].tolist(),
            lengths.tolist(), speeds.tolist(), distances.tolist(),
            (distances / speeds).tolist(), strict=True)):
        line, line_fracs = graph.line(row)
        coords, fracs = cut_with_fractions(line, line_fracs, a, b)
        runs.append(Run(Piece(row, a, b), sid, coords, fracs, length, speed, ends.b_out[k],
                        ends.b_in[k], distance, duration))
    return runs


def run_of(graph: RoadGraph, p: Piece) -> Run:
    """The run of one piece."""
    return runs_of(graph, np.array([p.row]), np.array([p.f_from]), np.array([p.f_to]))[0]


def trace(graph: RoadGraph, leg: Leg) -> Trace:
    """The leg's pieces and coordinates. What every answer needs is read for all pieces at
    once (a city route has ~100): whole segments contribute the graph's coordinates, only the
    cut ends are interpolated."""
    driven = leg.f_from != leg.f_to
    rows, f_from, f_to = leg.rows[driven], leg.f_from[driven], leg.f_to[driven]
    start, end = location(graph, leg.start), location(graph, leg.end)
    distance = np.abs(f_to - f_from) * graph.segs.length_m[rows]
    coords, starts = _coords(graph, rows, f_from, f_to, start, end)
    return Trace(leg, graph, rows, f_from, f_to, graph.segs.ids[rows], f_to >= f_from,
                 distance, distance / (graph.speed_kph[rows] / 3.6), coords, starts, start, end)


def _coords(graph: RoadGraph, rows: np.ndarray, f_from: np.ndarray, f_to: np.ndarray,
            start: list[float], end: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """A leg's coordinates (start point first, joints not repeated) and the index of each
    piece's first coordinate (then of the last): :func:`_gathered`."""
    if not len(rows):  # start and end coincide: OSRM still sends a two-point line
        return np.array([start, end]), np.array([0, 1])
    return _gathered(rows, f_from, f_to, graph.segs.offsets, graph.segs.coords, graph.fracs,
                     np.array(start, np.float64))


@kernel("Tuple((f8[:, :], i8[:]))(i8[:], f8[:], f8[:], i8[:], f8[:, :], f8[:], f8[:])")
def _gathered(rows: np.ndarray, f_from: np.ndarray, f_to: np.ndarray, offsets: np.ndarray,
              coords: np.ndarray, fracs: np.ndarray, start: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """The coordinates of the pieces (segment ``rows`` driven from ``f_from`` to ``f_to``)
    after ``start``, each piece's without its first (the joint), and the index of each piece's
    first coordinate, then of the last: a whole piece is its segment's vertices in driving
    order; a cut one (the leg's ends) is :func:`~app.routing.geometry.cut_with_fractions`'s
    line: the vertices strictly between its fractions, then the point at its far end,
    interpolated at the metric fraction."""
    m = len(rows)
    starts = np.zeros(m + 1, np.int64)
    for k in range(m):
        lo_f, hi_f = min(f_from[k], f_to[k]), max(f_from[k], f_to[k])
        a, b = offsets[rows[k]], offsets[rows[k] + 1]
        if lo_f == 0.0 and hi_f == 1.0:
            count = b - a - 1
        else:
            count = 1
            for v in range(a, b):
                count += lo_f < fracs[v] < hi_f
        starts[k + 1] = starts[k] + count
    out = np.empty((starts[m] + 1, 2))
    out[0] = start
    for k in range(m):
        a, b = offsets[rows[k]], offsets[rows[k] + 1]
        forward = f_to[k] >= f_from[k]
        lo_f, hi_f = min(f_from[k], f_to[k]), max(f_from[k], f_to[k])
        at = starts[k] + 1
        if lo_f == 0.0 and hi_f == 1.0:
            for v in range(b - a - 1):
                out[at + v] = coords[a + 1 + v] if forward else coords[b - 2 - v]
            continue
        inner = range(a, b) if forward else range(b - 1, a - 1, -1)
        for v in inner:
            if lo_f < fracs[v] < hi_f:
                out[at] = coords[v]
                at += 1
        far = f_to[k]
        out[at, 0] = np.interp(far, fracs[a:b], coords[a:b, 0])
        out[at, 1] = np.interp(far, fracs[a:b], coords[a:b, 1])
    return out, starts


def node_ids(graph: RoadGraph, t: Trace) -> list[int]:
    """OSRM's ``annotation.nodes`` for a leg: one id per coordinate. Segment ends are network
    node ids; inner vertices get :data:`VERTEX_BASE` ids; a snapped point takes the id of the
    vertex behind it (start) or ahead of it (end), so each consecutive pair of ids names the
    piece of road the pair lies on, as OSRM's OSM node pairs do."""
    if not len(t.rows):  # zero-length leg on one segment
        return nodes_around(graph, t.leg.start)
    ids: list[int] = []
    last = len(t.runs) - 1
    for n, run in enumerate(t.runs):
        _, line_fracs = graph.line(run.piece.row)
        for k, f in enumerate(run.fracs):
            if k == 0 and n > 0:
                continue  # the joint, already given by the previous run
            at = np.flatnonzero(line_fracs == f)
            if len(at):
                vertex = int(at[0] if run.forward else at[-1])
            else:  # a cut point: the vertex behind it at the start, ahead of it at the end
                behind = k == 0 and n == 0
                ahead = k == len(run.fracs) - 1 and n == last
                lower = int(np.searchsorted(line_fracs, f, side="right")) - 1
                use_lower = (behind and run.forward) or (ahead and not run.forward)
                vertex = lower if use_lower or not (behind or ahead) else lower + 1
            ids.append(_vertex_id(graph, run.piece.row, vertex))
    return ids


def nodes_around(graph: RoadGraph, snap: Snap) -> list[int]:
    """The ids (as ``annotation.nodes`` gives them) of the vertices before and after a snapped
    point along its segment: OSRM's ``nodes`` of a nearest waypoint."""
    row = graph.row_of(snap.segment_id)
    assert row is not None
    _, fracs = graph.line(row)
    k = min(max(int(np.searchsorted(fracs, snap.fraction, side="right")) - 1, 0),
            len(fracs) - 2)
    return [_vertex_id(graph, row, k), _vertex_id(graph, row, k + 1)]


def _vertex_id(graph: RoadGraph, row: int, vertex: int) -> int:
    n = int(graph.segs.offsets[row + 1] - graph.segs.offsets[row])
    if vertex == 0:
        return int(graph.segs.source[row])
    if vertex == n - 1:
        return int(graph.segs.target[row])
    return -(int(graph.segs.ids[row]) * VERTEX_BASE + vertex)
