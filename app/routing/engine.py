"""Shortest paths between snapped points, starting and ending mid-segment.

A snapped point sits at fraction ``f`` of segment (u -> v). Leaving it costs ``(1-f)·c`` to
reach v (if the segment may be driven along its geometry) and ``f·c`` to reach u (if it may be
driven against it); arriving is the mirror image, and two points on the same segment may also
be joined directly along it. One-way rules therefore hold on the snapped segments themselves.
A point within :data:`AT_NODE_M` of a segment end is *at* that node and may leave by any arc,
unless its snap restricts the directions (OSRM's ``bearings``/``approaches``): such a point is
left and reached only along its segment, in the directions the snap keeps.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from app.errors import NoRouteError
from app.routing.geometry import haversine_m, point_at
from app.routing.graph import CostGraph, RoadGraph
from app.routing.params import point
from app.routing.pieces import Pieces
from app.routing.snap import Snap

AT_NODE_M = 0.01
FIRST_LIMIT_FACTOR = 2.0  # first search bound, in straight-line costs
LIMIT_GROWTH = 3.0


@dataclass(frozen=True)
class Piece:
    """A traversed part of one segment, from fraction ``f_from`` to ``f_to``."""

    row: int
    f_from: float
    f_to: float


@dataclass(frozen=True, eq=False)
class Leg:
    """One leg of a route: its snapped ends, total weight and the segment pieces driven, as
    arrays (segment row, and the fractions each piece is driven from and to, in driving
    order). Arrays because a city leg drives ~100 pieces, and everything shaping the answer
    reads them as arrays: made as objects, they cost more than the search that found them;
    :attr:`pieces` makes them when a consumer walks the pieces one by one."""

    start: Snap
    end: Snap
    weight: float
    rows: np.ndarray
    f_from: np.ndarray
    f_to: np.ndarray

    @classmethod
    def of(cls, start: Snap, end: Snap, weight: float, pieces: Sequence[Piece]) -> Leg:
        """The leg driving ``pieces``."""
        n = len(pieces)
        return cls(start, end, weight, np.fromiter((p.row for p in pieces), np.int64, n),
                   np.fromiter((p.f_from for p in pieces), np.float64, n),
                   np.fromiter((p.f_to for p in pieces), np.float64, n))

    @cached_property
    def pieces(self) -> list[Piece]:
        """The pieces as objects."""
        return [Piece(*p) for p in zip(self.rows.tolist(), self.f_from.tolist(),
                                       self.f_to.tolist(), strict=True)]


@dataclass(frozen=True)
class Place:
    """A snap resolved against one graph: segment row and end-node indices."""

    snap: Snap
    row: int
    u: int
    v: int
    fraction: float
    at_node: int | None
    loc: tuple[float, float]  # lon/lat of the point on the segment


def place(graph: RoadGraph, snap: Snap) -> Place:
    """Where a snapped point lies on the graph, treating points within a centimetre of a node as
    at the node, so no zero-length piece is produced."""
    row = graph.row_of(snap.segment_id)
    if row is None:  # deleted between snapping and routing
        raise NoRouteError(f"segment {snap.segment_id} under {point(snap.index)} no longer "
                           "exists")
    length = float(graph.segs.length_m[row])
    u, v, f = int(graph.u[row]), int(graph.v[row]), snap.fraction
    at = u if f * length <= AT_NODE_M else v if (1 - f) * length <= AT_NODE_M else None
    if snap.restricted:
        at = None
    coords, fracs = graph.line(row)
    return Place(snap, row, u, v, f, at, point_at(coords, fracs, f))


def _ways(graph: RoadGraph, p: Place, way: int | None) -> tuple[bool, bool]:
    """(forward, backward): may the place's segment be driven along / against its geometry
    there, by its one-way rule, the snap's directions and the direction asked for (``way``)."""
    oneway = int(graph.segs.oneway[p.row])
    return (oneway >= 0 and p.snap.forward and way != -1,
            oneway <= 0 and p.snap.backward and way != 1)


def departures(graph: RoadGraph, cg: CostGraph, p: Place, way: int | None = None
               ) -> list[tuple[int, float, Piece | None]]:
    """(node, cost, piece) ways to leave a place onto the graph (only along its geometry,
    ``way`` +1, or against it, -1, when asked)."""
    if p.at_node is not None:
        return [(p.at_node, 0.0, None)]
    c = float(cg.seg_cost[p.row])
    forward, backward = _ways(graph, p, way)
    out: list[tuple[int, float, Piece | None]] = []
    if forward:
        out.append((p.v, (1 - p.fraction) * c, Piece(p.row, p.fraction, 1.0)))
    if backward:
        out.append((p.u, p.fraction * c, Piece(p.row, p.fraction, 0.0)))
    return out


def arrivals(graph: RoadGraph, cg: CostGraph, p: Place, way: int | None = None
             ) -> list[tuple[int, float, Piece | None]]:
    """(node, cost, piece) ways to reach a place from the graph (arriving along the geometry,
    ``way`` +1, or against it, -1, when asked)."""
    if p.at_node is not None:
        return [(p.at_node, 0.0, None)]
    c = float(cg.seg_cost[p.row])
    forward, backward = _ways(graph, p, way)
    out: list[tuple[int, float, Piece | None]] = []
    if forward:
        out.append((p.u, p.fraction * c, Piece(p.row, 0.0, p.fraction)))
    if backward:
        out.append((p.v, (1 - p.fraction) * c, Piece(p.row, 1.0, p.fraction)))
    return out


def direct(graph: RoadGraph, cg: CostGraph, a: Place, b: Place, out_way: int | None = None,
           in_way: int | None = None) -> tuple[float, Piece] | None:
    """Driving straight along a shared segment, when its direction allows."""
    if a.row != b.row or a.at_node is not None or b.at_node is not None:
        return None
    ahead = b.fraction >= a.fraction
    for p, way in ((a, out_way), (b, in_way)):
        forward, backward = _ways(graph, p, way)
        if not (forward if ahead else backward):
            return None
    return abs(b.fraction - a.fraction) * float(cg.seg_cost[a.row]), Piece(a.row, a.fraction,
                                                                          b.fraction)


class Router:
    """Searches one graph under one cost model for one request."""

    def __init__(self, graph: RoadGraph, cg: CostGraph, snaps: Sequence[Snap]) -> None:
        self.graph, self.cg = graph, cg
        self.places = [place(graph, s) for s in snaps]
        self._pieces: Pieces | None = None

    def _no_route(self, a: Place, b: Place) -> NoRouteError:
        """Why no route joins places a and b, in words (pieces found once per request)."""
        if self._pieces is None:
            self._pieces = Pieces.of(self.graph, self.cg)
        return self._pieces.no_route(a.snap.index, a.row, b.snap.index, b.row)

    def _first_limit(self, a: Place, b: Place) -> float:
        """A cost bound that usually covers the route: a few times the straight-line cost."""
        crow = haversine_m(a.loc, b.loc) / self.cg.max_rate
        c_a, c_b = (float(self.cg.seg_cost[p.row]) for p in (a, b))
        return FIRST_LIMIT_FACTOR * crow + c_a + c_b + 1.0

    def leg(self, i: int, j: int, out_way: int | None = None, in_way: int | None = None) -> Leg:
        """Cheapest way from place i to place j: through the network's contraction hierarchy
        when it can answer for this graph version, else by bounded Dijkstra. ``out_way`` and
        ``in_way`` (+1 along the snapped segment's geometry, -1 against it) pin the direction
        of leaving i and reaching j."""
        a, b = self.places[i], self.places[j]
        outs = departures(self.graph, self.cg, a, out_way)
        ins = arrivals(self.graph, self.cg, b, in_way)
        straight = direct(self.graph, self.cg, a, b, out_way, in_way)
        if not (outs and ins):
            if straight:
                return Leg.of(a.snap, b.snap, straight[0], [straight[1]])
            raise self._no_route(a, b)
        found = self.cg.fast_path([(n, c) for n, c, _ in outs], [(n, c) for n, c, _ in ins])
        if found is not None:
            k, m, rows, ways = found
            first, last = outs[k][2], ins[m][2]
            weight = outs[k][1] + float(self.cg.seg_cost[rows].sum()) + ins[m][1]
        else:
            weight, first, rows, ways, last = self._dijkstra(a, b, outs, ins)
        if straight and straight[0] <= weight:
            return Leg.of(a.snap, b.snap, straight[0], [straight[1]])
        if not np.isfinite(weight):
            raise self._no_route(a, b)
        # The piece leaving a (none when a is at a node), whole segments driven along (+1) or
        # against their geometry, the piece reaching b.
        f_from = np.where(ways > 0, 0.0, 1.0)
        head, tail = [first] if first is not None else [], [last] if last is not None else []
        return Leg(a.snap, b.snap, weight,
                   np.concatenate([[p.row for p in head], rows, [p.row for p in tail]]
                                  ).astype(np.int64),
                   np.concatenate([[p.f_from for p in head], f_from, [p.f_from for p in tail]]),
                   np.concatenate([[p.f_to for p in head], 1.0 - f_from,
                                   [p.f_to for p in tail]]))

    def legs(self, seq: Sequence[int], continue_straight: bool = False) -> list[Leg]:
        """The legs visiting the places ``seq`` in order. With ``continue_straight`` (OSRM's
        option) no route turns back at an intermediate point: it leaves in the direction it
        arrived, chosen over all points at once (up to four searches per leg); points at a
        node are not constrained (any arc there is a way on)."""
        pairs = list(itertools.pairwise(seq))
        if not continue_straight or len(seq) < 3:
            return [self.leg(i, j) for i, j in pairs]
        ways = [[None] if k in (0, len(seq) - 1) or self.places[p].at_node is not None
                else [1, -1] for k, p in enumerate(seq)]
        best: dict[int | None, tuple[float, list[Leg]]] = {None: (0.0, [])}
        for k, (i, j) in enumerate(pairs):
            nxt: dict[int | None, tuple[float, list[Leg]]] = {}
            for out_way, (cost, done) in best.items():
                for in_way in ways[k + 1]:
                    try:
                        leg = self.leg(i, j, out_way, in_way)
                    except NoRouteError:
                        continue
                    if in_way not in nxt or cost + leg.weight < nxt[in_way][0]:
                        nxt[in_way] = (cost + leg.weight, [*done, leg])
            if not nxt:
                raise NoRouteError(f"no route from {point(i)} to {point(j)} that keeps "
                                   "going straight at the points (continue_straight=true)")
            best = nxt
        return best[None][1]

    def _dijkstra(self, a: Place, b: Place, outs: list, ins: list
                  ) -> tuple[float, Piece | None, np.ndarray, np.ndarray, Piece | None]:
        """(weight, first piece, segment rows, directions, last piece) by Dijkstra.

        The search is bounded (scipy's ``limit``) and the bound grows until the best arrival
        lies within it: every node cheaper than the bound has its exact cost, so a route found
        within the bound is optimal. Short legs on a large network then touch only the
        neighbourhood of their end points instead of the whole graph.
        """
        limit = self._first_limit(a, b)
        while True:
            if limit > self.cg.total_cost:
                limit = np.inf
            dist, pred = self.cg.search(((n, c) for n, c, _ in outs), limit=limit)
            weight, end_node, last = np.inf, -1, None
            for n, c, piece in ins:
                if dist[n] + c < weight:
                    weight, end_node, last = float(dist[n] + c), n, piece
            if weight <= limit or limit == np.inf:
                break
            limit *= LIMIT_GROWTH
        if not np.isfinite(weight):
            return weight, None, np.zeros(0, np.int64), np.zeros(0, np.int8), None
        nodes = [end_node]
        while pred[nodes[-1]] != self.cg.origin:
            nodes.append(int(pred[nodes[-1]]))
        nodes.reverse()
        _, first = min(((c, piece) for n, c, piece in outs if n == nodes[0]),
                       key=lambda cp: cp[0])
        rows, ways = self.cg.path_arcs(nodes)
        return weight, first, rows, ways, last
