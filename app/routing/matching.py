"""Map matching (OSRM's match service): the roads a GNSS trace drove, by a hidden Markov model.

Newson & Krumm's model (2009), with OSRM's constants where it has them: each trace point's
hidden state is one of the road positions within 3 sigma of it (sigma: the point's GPS
precision, ``radiuses=``, 5 m by default); a position's emission log-probability is
``-(d / sigma)^2 / 2`` for its distance ``d`` from the point, and a transition between
positions of consecutive points costs ``|network distance - great-circle distance| / beta``
(beta = 10 m, OSRM's ``MATCHING_BETA``). Viterbi picks the likeliest positions. Where no
position of a point can be reached from any of the previous point's (within a bound on the
detour, and within 180 km/h when timestamps are given, OSRM's car speed) the trace splits
into separate matchings, as it does at a time gap longer than 10 times the median sampling
interval (``gaps=split``, OSRM's rule). A point with no road within 3 sigma is left out.

Why written here rather than taken from PyPI: the one maintained HMM matcher that takes a
custom graph, leuvenmapmatching (1.1.4, last released 2022), runs its Viterbi in pure Python
(75 points in 0.49 s in the team's research measurement, so ~6.5 s for the 1,000-point trace
a planner sends) and keeps its own copy of the graph, which live edits would not reach;
gpsmatcher is GPL-3 and a 0.1 release; mappymatch is LCSS, not an HMM; mapmatcher is a
cost-discounted shortest path.
Here the candidates come from the live graph's index (:mod:`app.routing.nearby`) and the
transitions from scipy's compiled Dijkstra on the trace's corridor of that graph (the
segments near the trace, a few thousand arcs however large the network), one call per step
for all candidates at once; Viterbi is a numpy max over each step's small matrix.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from app.routing.budget import Budget
from app.routing.engine import Piece, Place, arrivals, departures, direct, place
from app.routing.geometry import haversine_m
from app.routing.graph import CostGraph, RoadGraph
from app.routing.nearby import within
from app.routing.options import PointOptions
from app.routing.snap import Snap, fitting

SEARCH_SIGMAS = 3.0  # candidates within this many standard deviations (OSRM's 3)
MAX_CANDIDATES = 8  # per point, nearest first
BETA_M = 10.0  # OSRM's MATCHING_BETA
MAX_SPEED_MS = 180 / 3.6  # OSRM's car max_speed_for_map_matching
GAP_FACTOR = 10.0  # gaps=split: a gap longer than this many median intervals splits
TIDY_M, TIDY_S = 15.0, 5.0  # tidy=true drops points this close to the last one kept
CORRIDOR_M = 100.0  # the trace's corridor: this much around each step, plus a quarter of it
DETOUR_M = 200.0  # a step's route may be this much + twice its great-circle distance


@dataclass(frozen=True)
class Track:
    """A trace to match: points, their GPS precisions and options, timestamps if any."""

    points: Sequence[tuple[float, float]]
    snap: Sequence[PointOptions]  # radius_m is the point's sigma
    timestamps: Sequence[int] | None
    split_gaps: bool
    tidy: bool


@dataclass(frozen=True)
class Matching:
    """One run of the trace matched without a break: the points it holds (input indices, in
    order) and the road position chosen for each, and the other candidates' count."""

    points: list[int]
    snaps: list[Snap]
    alternatives: list[int]


def tidied(trace: Track) -> list[int]:
    """The points kept by ``tidy`` (all of them without it): each at least 15 m or 5 s from
    the previous one kept, and always the last."""
    n = len(trace.points)
    if not trace.tidy:
        return list(range(n))
    kept = [0]
    for i in range(1, n):
        far = haversine_m(trace.points[kept[-1]], trace.points[i]) >= TIDY_M
        later = trace.timestamps is not None and \
            trace.timestamps[i] - trace.timestamps[kept[-1]] >= TIDY_S
        if far or later or i == n - 1:
            kept.append(i)
    return kept


def _gap_limit(trace: Track) -> float:
    """The time step beyond which ``gaps=split`` splits the trace (inf when it does not)."""
    if trace.timestamps is None or not trace.split_gaps or len(trace.timestamps) < 2:
        return math.inf
    steps = np.diff(np.asarray(trace.timestamps, np.float64))
    steps = steps[steps > 0]
    return GAP_FACTOR * float(np.median(steps)) if len(steps) else math.inf


class _Corridor:
    """The cost graph restricted to the segments near the trace, as a small CSR matrix."""

    def __init__(self, graph: RoadGraph, cg: CostGraph, points: np.ndarray, sigma: float
                 ) -> None:
        a, b = points[:-1], points[1:]
        east = np.cos(np.radians(points[:, 1].mean())) * 111_320.0
        gap = np.hypot((b[:, 0] - a[:, 0]) * east, (b[:, 1] - a[:, 1]) * 111_320.0)
        margin_m = CORRIDOR_M + SEARCH_SIGMAS * sigma + gap / 4
        dlat, dlon = margin_m / 111_320.0, margin_m / max(east, 1.0)
        boxes = np.column_stack([np.minimum(a[:, 0], b[:, 0]) - dlon,
                                 np.minimum(a[:, 1], b[:, 1]) - dlat,
                                 np.maximum(a[:, 0], b[:, 0]) + dlon,
                                 np.maximum(a[:, 1], b[:, 1]) + dlat])
        rows = np.unique(graph.index.pairs(graph, boxes)[1])
        arcs = cg.arcs.of_rows(rows)
        arcs = arcs[np.isfinite(cg.arc_costs[arcs])]
        self.nodes, local = np.unique(np.concatenate([cg.arcs.tail[arcs], cg.arcs.head[arcs]]),
                                      return_inverse=True)
        tail, head = local[: len(arcs)], local[len(arcs):]
        costs, n = cg.arc_costs[arcs], len(self.nodes)
        # Parallel segments: keep the cheaper (a sparse matrix would add them up).
        key = tail.astype(np.int64) * n + head
        order = np.lexsort((costs, key))
        first = np.ones(len(order), bool)
        first[1:] = key[order][1:] != key[order][:-1]
        keep = order[first]
        self.matrix = csr_matrix((costs[keep], (tail[keep], head[keep])), shape=(n, n))

    def local(self, nodes: np.ndarray) -> np.ndarray:
        """Corridor indices of graph ``nodes`` (-1 for a node outside it)."""
        if not len(self.nodes):
            return np.full(len(nodes), -1, np.int64)
        at = np.minimum(np.searchsorted(self.nodes, nodes), len(self.nodes) - 1)
        return np.where(self.nodes[at] == nodes, at, -1)


@dataclass(frozen=True)
class _Ends:
    """Each candidate's ways onto (departures) or off (arrivals) the corridor: up to two
    (corridor node, metres) per candidate, padded with node -1 at infinite cost."""

    node: np.ndarray  # (k, 2)
    cost: np.ndarray  # (k, 2)


def _ends(corridor: _Corridor, ways: list[list[tuple[int, float, Piece | None]]]) -> _Ends:
    node = np.full((len(ways), 2), -1, np.int64)
    cost = np.full((len(ways), 2), np.inf)
    for i, found in enumerate(ways):
        for k, (n, c, _) in enumerate(found[:2]):
            node[i, k], cost[i, k] = n, c
    local = np.where(node >= 0, corridor.local(np.maximum(node, 0).ravel()).reshape(node.shape),
                     -1)
    cost[local < 0] = np.inf
    return _Ends(local, cost)


@dataclass
class _Point:
    """A trace point's candidates, their places on the graph and emission log-probabilities."""

    index: int
    snaps: list[Snap]
    places: list[Place]
    emission: np.ndarray
    outs: _Ends
    ins: _Ends


def _network_distances(graph: RoadGraph, cg: CostGraph, corridor: _Corridor, p: _Point,
                       q: _Point, limit: float) -> np.ndarray:
    """Metres by road from each candidate of ``p`` to each of ``q`` (inf beyond ``limit``)."""
    sources = np.unique(p.outs.node[p.outs.node >= 0])
    out = np.full((len(p.places), len(q.places)), np.inf)
    if len(sources):
        d = dijkstra(corridor.matrix, directed=True, indices=sources, limit=limit)
        d = np.concatenate([d, np.full((len(sources), 1), np.inf)], axis=1)  # column -1: none
        row_of = np.searchsorted(sources, np.maximum(p.outs.node, 0))
        for a in range(2):
            reach = d[row_of[:, a]]  # (kp, n + 1)
            for b in range(2):
                cells = p.outs.cost[:, a, None] + reach[:, q.ins.node[:, b]] \
                    + q.ins.cost[None, :, b]
                np.minimum(out, cells, out=out)
    for i, here in enumerate(p.places):  # the same segment, straight along it
        for j, there in enumerate(q.places):
            if here.row == there.row:
                straight = direct(graph, cg, here, there)
                if straight is not None:
                    out[i, j] = min(out[i, j], straight[0])
    out[out > limit] = np.inf
    return out


def match(graph: RoadGraph, cg: CostGraph, trace: Track, avoid: frozenset[str],
          budget: Budget) -> list[Matching]:
    """The trace's matchings (each at least two points), in trace order; ``cg`` prices by
    distance. Raises ``TooBig`` once ``budget`` is spent."""
    kept = tidied(trace)
    pts = np.array([trace.points[i] for i in kept], np.float64).reshape(-1, 2)
    sigma = np.array([trace.snap[i].radius_m for i in kept])
    hits = within(graph, pts, SEARCH_SIGMAS * sigma, avoid)
    candidates: list[_Point] = []
    corridor = _Corridor(graph, cg, pts, float(sigma.max()))
    for k, i in enumerate(kept):
        budget.check()
        opts = trace.snap[i]
        search = PointOptions(SEARCH_SIGMAS * opts.radius_m, opts.bearing, opts.approach)
        snaps = []
        for snap in fitting(graph, hits.of(k), i, trace.points[i], search):
            snaps.append(snap)
            if len(snaps) == MAX_CANDIDATES:
                break
        if not snaps:
            continue  # no road near it: left out, the chain goes on from the previous point
        places = [place(graph, s) for s in snaps]
        d = np.array([s.distance_m for s in snaps])
        candidates.append(_Point(
            i, snaps, places, -0.5 * (d / max(opts.radius_m, 0.1)) ** 2,
            _ends(corridor, [departures(graph, cg, pl) for pl in places]),
            _ends(corridor, [arrivals(graph, cg, pl) for pl in places])))
    return _viterbi(graph, cg, corridor, trace, candidates, budget)


@dataclass
class _Chain:
    """A run of points being matched: their candidates, the best predecessor of each
    candidate at each step, and the running log-probabilities of the last point's."""

    points: list[_Point]
    backs: list[np.ndarray]
    score: np.ndarray

    def matching(self) -> Matching:
        """The likeliest candidate of every point, read back from the last one."""
        k = int(np.argmax(self.score))
        chosen = [k]
        for back in reversed(self.backs):
            k = int(back[k])
            chosen.append(k)
        chosen.reverse()
        return Matching([p.index for p in self.points],
                        [p.snaps[k] for p, k in zip(self.points, chosen, strict=True)],
                        [len(p.snaps) - 1 for p in self.points])


def _step_limit(trace: Track, p: int, q: int, crow: float) -> float:
    """The longest road distance believed between trace points ``p`` and ``q``: a detour
    bound, and with timestamps what 180 km/h covers."""
    limit = 2 * crow + DETOUR_M + 2 * SEARCH_SIGMAS * (trace.snap[p].radius_m
                                                       + trace.snap[q].radius_m)
    if trace.timestamps is not None:
        dt = trace.timestamps[q] - trace.timestamps[p]
        limit = min(limit, max(dt, 1) * MAX_SPEED_MS + crow)
    return limit


def _viterbi(graph: RoadGraph, cg: CostGraph, corridor: _Corridor, trace: Track,
             candidates: list[_Point], budget: Budget) -> list[Matching]:
    """The likeliest candidates, chain by chain: a chain ends where no candidate of the next
    point can be reached from any of the last one's, or at a time gap (``gaps=split``)."""
    gap = _gap_limit(trace)
    chains: list[_Chain] = []
    for q in candidates:
        budget.check()
        step = None
        if chains:
            chain = chains[-1]
            p = chain.points[-1]
            waited = (trace.timestamps[q.index] - trace.timestamps[p.index]
                      if trace.timestamps is not None else 0)
            if waited <= gap:
                crow = haversine_m(trace.points[p.index], trace.points[q.index])
                road = _network_distances(graph, cg, corridor, p, q,
                                          _step_limit(trace, p.index, q.index, crow))
                step = chain.score[:, None] - np.abs(road - crow) / BETA_M
                if not np.isfinite(step).any():
                    step = None
        if step is None:
            chains.append(_Chain([q], [], q.emission.copy()))
            continue
        best = np.argmax(step, axis=0)
        chain.score = step[best, np.arange(step.shape[1])] + q.emission
        chain.points.append(q)
        chain.backs.append(best)
    # A lone point matches no road travelled: OSRM leaves it out too.
    return [_through_junctions(graph, trace, c.matching()) for c in chains
            if len(c.points) >= 2]


def _through_junctions(graph: RoadGraph, trace: Track, m: Matching) -> Matching:
    """Inner points matched a few metres into a side road, off the roads their neighbours
    matched, moved to the junction: GPS noise near a crossing otherwise turns a straight
    drive into a detour of a few metres into the side road and back. A point within its
    search radius of the node is as likely at the node."""
    snaps = list(m.snaps)
    for k in range(1, len(snaps) - 1):
        s = snaps[k]
        if s.segment_id in (snaps[k - 1].segment_id, snaps[k + 1].segment_id):
            continue
        row = graph.row_of(s.segment_id)
        assert row is not None
        length = float(graph.segs.length_m[row])
        near_m = SEARCH_SIGMAS * trace.snap[s.index].radius_m
        end = 0.0 if s.fraction * length <= near_m else \
            1.0 if (1.0 - s.fraction) * length <= near_m else None
        if end is not None:
            coords, _ = graph.line(row)
            node = coords[0] if end == 0.0 else coords[-1]
            snaps[k] = replace(s, fraction=end, distance_m=haversine_m(s.point, tuple(node)))
    return replace(m, snaps=snaps)
