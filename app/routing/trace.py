"""A leg as runs: each driven segment piece with its coordinates and what driving it costs.

Built once per leg and shared by everything that shapes the answer (overview geometry,
annotations, steps, the per-leg ``segments`` list), so no part re-cuts a segment or re-prices a
coordinate pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.routing.costs import Cost
from app.routing.engine import Leg, Piece
from app.routing.geometry import bearing, cut_with_fractions, point_at
from app.routing.graph import RoadGraph
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
    coords: list[list[float]]
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

    def weight(self, cost: Cost) -> float:
        """What the route minimises over this run."""
        return self.duration if cost is Cost.TIME else self.distance

    @property
    def starts_at_node(self) -> bool:
        """The run begins at a segment end (not at a snapped point)."""
        return self.piece.f_from in (0.0, 1.0)


@dataclass(frozen=True)
class Trace:
    """A leg's runs and its coordinates (start point first, joints not repeated)."""

    leg: Leg
    runs: list[Run]
    coords: list[list[float]]
    start: list[float]
    end: list[float]


def location(graph: RoadGraph, snap: Snap) -> list[float]:
    """Where a snapped point lies on its segment (lon, lat)."""
    row = graph.row_of(snap.segment_id)
    assert row is not None  # the route was planned on this graph, so it holds the snaps
    coords, fracs = graph.line(row)
    return list(point_at(coords, fracs, snap.fraction))


def run_of(graph: RoadGraph, p: Piece) -> Run:
    """The run of one piece: coordinates cut at its fractions, bearings at its ends."""
    line, line_fracs = graph.line(p.row)
    coords, fracs = cut_with_fractions(line, line_fracs, p.f_from, p.f_to)
    length = float(graph.segs.length_m[p.row])
    if (p.f_from, p.f_to) == (0.0, 1.0):  # whole segments: bearings precomputed per graph
        b_out, b_in = float(graph.bearing_start[p.row]), float(graph.bearing_end[p.row])
    elif (p.f_from, p.f_to) == (1.0, 0.0):
        b_out = (float(graph.bearing_end[p.row]) + 180.0) % 360.0
        b_in = (float(graph.bearing_start[p.row]) + 180.0) % 360.0
    else:
        b_out, b_in = bearing(coords[0], coords[1]), bearing(coords[-2], coords[-1])
    speed_ms = float(graph.speed_kph[p.row]) / 3.6
    distance = abs(p.f_to - p.f_from) * length
    return Run(p, int(graph.segs.ids[p.row]), coords, fracs, length, speed_ms, b_out, b_in,
               distance, distance / speed_ms)


def trace(graph: RoadGraph, leg: Leg) -> Trace:
    """The leg's runs (zero-length pieces dropped) and coordinates."""
    runs = [run_of(graph, p) for p in leg.pieces if p.f_from != p.f_to]
    start, end = location(graph, leg.start), location(graph, leg.end)
    coords = [start]
    for run in runs:
        coords.extend(run.coords[1:])
    if len(coords) == 1:  # start and end coincide: OSRM still sends a two-point line
        coords.append(end)
    return Trace(leg, runs, coords, start, end)


def node_ids(graph: RoadGraph, t: Trace) -> list[int]:
    """OSRM's ``annotation.nodes`` for a leg: one id per coordinate. Segment ends are network
    node ids; inner vertices get :data:`VERTEX_BASE` ids; a snapped point takes the id of the
    vertex behind it (start) or ahead of it (end), so each consecutive pair of ids names the
    piece of road the pair lies on, as OSRM's OSM node pairs do."""
    if not t.runs:  # zero-length leg on one segment
        row = graph.row_of(t.leg.start.segment_id)
        assert row is not None
        _, fracs = graph.line(row)
        f = t.leg.start.fraction
        k = int(np.searchsorted(fracs, f, side="right")) - 1
        return [_vertex_id(graph, row, max(k, 0)),
                _vertex_id(graph, row, min(k + 1, len(fracs) - 1))]
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


def _vertex_id(graph: RoadGraph, row: int, vertex: int) -> int:
    n = int(graph.segs.offsets[row + 1] - graph.segs.offsets[row])
    if vertex == 0:
        return int(graph.segs.source[row])
    if vertex == n - 1:
        return int(graph.segs.target[row])
    return -(int(graph.segs.ids[row]) * VERTEX_BASE + vertex)
