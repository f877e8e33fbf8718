"""Cost matrices between snapped points: OSRM's table service, and the costs trip and
``optimize=true`` order points by.

Each cell is what the route between the two points would cost: leaving the source place and
reaching the destination place exactly as :class:`app.routing.engine.Router` does (partial
segments, one-way rules, the same-segment shortcut). Two ways to fill a matrix:

- **Through the hierarchy** (networks with a contraction hierarchy whose metric is at the
  graph's version): one many-to-many call over every departure and arrival node, then the
  partial costs added per cell. It gives the cost the route minimises (its ``weight``: the
  duration with ``cost=time``), quantised like the hierarchy's routes (a few 1e-5 s per
  segment). 100 x 100 on a city network: well under a millisecond.
- **By one Dijkstra per source** (small networks, a hierarchy not ready, or when the other
  annotation is asked for: the distance of the fastest route is not a cost the search
  minimises): scipy's search from the source gives every node's cost and predecessor, and
  the other quantity is summed along that tree by pointer jumping (log depth numpy passes), so
  a cell's duration and distance are those of the same route, exact.

A time budget (``UGVMAP_ROUTING_TIME_BUDGET_S``) bounds the per-source searches: beyond it the
request is refused with OSRM's ``TooBig``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.sparse.csgraph import dijkstra

from app.routing.budget import Budget
from app.routing.costs import Cost
from app.routing.engine import Piece, Place, arrivals, departures, direct
from app.routing.graph import CostGraph, RoadGraph

TREE_BATCH_CELLS = 4_000_000  # nodes x searches per scipy call (bounds its arrays to ~100 MB)


@dataclass(frozen=True)
class Matrices:
    """Per (source, destination): the route's weight and, when asked, duration and distance
    (``inf`` where no route joins them)."""

    weight: np.ndarray
    duration: np.ndarray | None = None
    distance: np.ndarray | None = None


def weight_quantity(cost: Cost) -> str:
    """The quantity a cost model's weight is (``duration`` for time, ``distance``)."""
    return "duration" if cost is Cost.TIME else "distance"


def _per_row(graph: RoadGraph, quantity: str) -> np.ndarray:
    """A whole segment's duration (s) or distance (m), per row."""
    if quantity == "distance":
        return graph.segs.length_m
    return graph.segs.length_m / (graph.speed_kph / 3.6)


def _piece(values: np.ndarray, piece: Piece | None) -> float:
    """A quantity over a partial segment (zero when the place is at a node)."""
    return 0.0 if piece is None else abs(piece.f_to - piece.f_from) * float(values[piece.row])


@dataclass(frozen=True)
class _Ends:
    """Up to two (node, cost, other quantity) ends per place, padded with a dummy node of
    infinite cost so every place has exactly two."""

    node: np.ndarray  # (n, 2) graph node, or ``pad`` for none
    cost: np.ndarray  # (n, 2)
    other: np.ndarray  # (n, 2)

    @classmethod
    def of(cls, ends: Sequence[list[tuple[int, float, Piece | None]]], pad: int,
           other: np.ndarray | None) -> _Ends:
        node = np.full((len(ends), 2), pad, np.int64)
        cost = np.full((len(ends), 2), np.inf)
        qty = np.zeros((len(ends), 2))
        for i, found in enumerate(ends):
            for k, (n, c, piece) in enumerate(found[:2]):
                node[i, k], cost[i, k] = n, c
                if other is not None:
                    qty[i, k] = _piece(other, piece)
        return cls(node, cost, qty)


def matrices(graph: RoadGraph, cg: CostGraph, sources: Sequence[Place],
             destinations: Sequence[Place], quantities: frozenset[str] = frozenset()
             ) -> Matrices:
    """The weight matrix, plus the ``quantities`` (duration, distance) asked for."""
    mine = weight_quantity(cg.cost)
    others = quantities - {mine}
    other = next(iter(others)) if others else None
    weight = None if other is not None else _by_hierarchy(graph, cg, sources, destinations)
    other_values = None
    if weight is None:
        weight, other_values = _by_trees(graph, cg, sources, destinations, other)
    _same_segment(graph, cg, sources, destinations, weight, other_values, other)
    by_name = {mine: weight, **({other: other_values} if other is not None else {})}
    return Matrices(weight, by_name.get("duration") if "duration" in quantities else None,
                    by_name.get("distance") if "distance" in quantities else None)


def _by_hierarchy(graph: RoadGraph, cg: CostGraph, sources: Sequence[Place],
                  destinations: Sequence[Place]) -> np.ndarray | None:
    """The weights through one many-to-many call, or ``None`` when the hierarchy cannot
    answer for this graph version."""
    metric = cg.metric()
    if metric is None:
        return None
    pad = graph.n_nodes  # a node no end uses; its row and column are dropped below
    outs = _Ends.of([departures(graph, cg, p) for p in sources], pad, None)
    ins = _Ends.of([arrivals(graph, cg, p) for p in destinations], pad, None)
    src, src_at = np.unique(outs.node, return_inverse=True)
    dst, dst_at = np.unique(ins.node, return_inverse=True)
    real_src, real_dst = src[src < pad], dst[dst < pad]
    core = metric.many_to_many(cg.version, real_src, real_dst)
    if core is None:
        return None
    full = np.full((len(src), len(dst)), np.inf)
    full[: len(real_src), : len(real_dst)] = core  # the pad sorts last in both
    src_at, dst_at = src_at.reshape(outs.node.shape), dst_at.reshape(ins.node.shape)
    weight = np.full((len(sources), len(destinations)), np.inf)
    for a in range(2):
        for b in range(2):
            cells = (outs.cost[:, a, None] + full[src_at[:, a]][:, dst_at[:, b]]
                     + ins.cost[None, :, b])
            np.minimum(weight, cells, out=weight)
    return weight


def _by_trees(graph: RoadGraph, cg: CostGraph, sources: Sequence[Place],
              destinations: Sequence[Place], other: str | None
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """Weights (and ``other`` along the same routes) from one Dijkstra per departure node:
    scipy searches a batch of them in one call, and the other quantity is summed along all of
    the batch's trees at once."""
    budget = Budget("the table", "ask for fewer sources or annotations=duration")
    values = _per_row(graph, other) if other is not None else None
    pad = cg.origin + 1  # one past the search's nodes: each row gets an inf appended there
    outs = _Ends.of([departures(graph, cg, p) for p in sources], pad, values)
    ins = _Ends.of([arrivals(graph, cg, p) for p in destinations], pad, values)
    starts = np.unique(outs.node[outs.node < pad])
    batch = max(1, TREE_BATCH_CELLS // pad)
    weight = np.full((len(sources), len(destinations)), np.inf)
    other_m = np.full_like(weight, np.inf) if values is not None else None
    for lo in range(0, len(starts), batch):
        budget.check(f" after {lo} of {len(starts)} sources")
        chunk = starts[lo:lo + batch]
        with cg.lock:  # the virtual origin's slots are never reached from a real node
            dist, pred = dijkstra(cg.matrix_unlocked(), directed=True, indices=chunk,
                                  return_predecessors=True)
        dist = np.concatenate([dist, np.full((len(chunk), 1), np.inf)], axis=1)
        along = None
        if values is not None:
            along = np.concatenate([_along_trees(cg, pred, values),
                                    np.full((len(chunk), 1), np.inf)], axis=1)
        for a in range(2):  # each source's departures whose node this batch searched from
            mine = np.flatnonzero(np.isin(outs.node[:, a], chunk))
            row = np.searchsorted(chunk, outs.node[mine, a])
            for b in range(2):
                cells = (outs.cost[mine, a, None] + dist[row][:, ins.node[:, b]]
                         + ins.cost[None, :, b])
                better = cells < weight[mine]
                weight[mine] = np.where(better, cells, weight[mine])
                if other_m is not None and along is not None:
                    more = (outs.other[mine, a, None] + along[row][:, ins.node[:, b]]
                            + ins.other[None, :, b])
                    other_m[mine] = np.where(better, more, other_m[mine])
    return weight, other_m


def _along_trees(cg: CostGraph, pred: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Per search (row) and node, the sum of ``values`` (per segment row) along the node's
    shortest-path-tree path from the search's root: each node's arc from its predecessor,
    then pointer jumping (every node adds its parent's sum and skips to its grandparent,
    until all hang from the root or are unreachable: log-depth passes), all trees at once."""
    k, n = pred.shape
    parent = np.where(pred < 0, np.arange(n)[None, :], pred).astype(np.int64)
    step = np.zeros((k, n))
    r, v = np.nonzero(pred >= 0)
    arcs = cg.arcs.cheapest(pred[r, v], v, cg.weights)
    step[r, v] = values[cg.arcs.row[arcs]]
    while True:
        grand = np.take_along_axis(parent, parent, axis=1)
        if np.array_equal(grand, parent):
            return step
        step = step + np.take_along_axis(step, parent, axis=1)
        parent = grand


def _same_segment(graph: RoadGraph, cg: CostGraph, sources: Sequence[Place],
                  destinations: Sequence[Place], weight: np.ndarray,
                  other_m: np.ndarray | None, other: str | None) -> None:
    """Cells whose two places share a segment that may be driven straight along between
    them, when that beats the way round (the same shortcut the route takes)."""
    values = _per_row(graph, other) if other is not None else None
    by_row: dict[int, list[int]] = {}
    for j, b in enumerate(destinations):
        by_row.setdefault(b.row, []).append(j)
    for i, a in enumerate(sources):
        for j in by_row.get(a.row, []):
            straight = direct(graph, cg, a, destinations[j])
            if straight is not None and straight[0] <= weight[i, j]:
                weight[i, j] = straight[0]
                if other_m is not None and values is not None:
                    other_m[i, j] = _piece(values, straight[1])
