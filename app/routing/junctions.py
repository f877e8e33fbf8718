"""Which roads meet at each node of a graph, for OSRM's step ``intersections`` and exit counts.

An index of the segment ends grouped by node, built on the first request that asks for steps
and kept per graph *shape* (node set and segment ends, shared by the graph versions of
attribute-only edits), so an edit of a speed limit or a one-way rule does not rebuild it
(~1 s for a million segments on the shared dev box). One-way rules and avoided classes, which
such edits change, are read from the current graph at each query.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.routing.graph import RoadGraph, Shape
from app.routing.native import kernel

KEEP = 2  # shapes whose index is kept (each ~5 bytes per segment end + 8 per node)


@dataclass(frozen=True)
class Road:
    """One road at a node: the segment row, whether the node is its target end, and the bearing
    pointing away from the node along it."""

    row: int
    at_target: bool
    bearing: int  # degrees, rounded as OSRM sends them


class Junctions:
    """Roads per node of one graph shape, as arrays sorted by node, then clockwise from north
    (bearing, row, end): a step's intersection is read off a slice, not rebuilt per node."""

    def __init__(self, shape: Shape) -> None:
        self.shape = shape  # held so the cache key (its id) cannot be reused
        m = len(shape.u)
        ends = np.concatenate([shape.u, shape.v])
        at_target = np.arange(2 * m) >= m
        row = np.arange(2 * m) % max(m, 1)
        away = np.where(at_target, shape.bearing_end[row] + 180.0, shape.bearing_start[row])
        bearing = np.round(away).astype(np.int64) % 360  # half to even, like round()
        order = np.lexsort((at_target, row, bearing, ends))
        self.row = row[order].astype(np.int64)
        self.at_target = at_target[order]
        self.bearing = bearing[order]
        self.offsets = np.concatenate(
            [[0], np.cumsum(np.bincount(ends, minlength=len(shape.node_ids)))])
        # Per node asked for: (rows, at_target, bearings) as lists; a node has a handful of
        # roads, where Python lists beat numpy slices (a city route passes ~70 junctions).
        self._lists: dict[int, tuple[list[int], list[bool], list[int]]] = {}

    def _at(self, node: int) -> tuple[list[int], list[bool], list[int]]:
        found = self._lists.get(node)
        if found is None:
            lo, hi = int(self.offsets[node]), int(self.offsets[node + 1])
            found = self._lists[node] = (self.row[lo:hi].tolist(),
                                         self.at_target[lo:hi].tolist(),
                                         self.bearing[lo:hi].tolist())
        return found

    def roads(self, node: int) -> list[Road]:
        """The roads at ``node`` (a graph node index), clockwise from north."""
        return [Road(r, t, b) for r, t, b in zip(*self._at(node), strict=True)]

    @staticmethod
    def enterable(graph: RoadGraph, road: Road, avoid: frozenset[str]) -> bool:
        """May a vehicle leave the node along this road (one-way rules, avoided classes)?"""
        s = graph.segs
        if str(s.road_class[road.row]) in avoid:
            return False
        way = int(s.oneway[road.row])
        return way <= 0 if road.at_target else way >= 0

    def crossings(self, graph: RoadGraph, nodes: np.ndarray, came: tuple[np.ndarray, np.ndarray],
                  leaves: tuple[np.ndarray, np.ndarray], avoid: frozenset[str]) -> Crossings:
        """The roads at each of ``nodes`` (a leg's joints), read for all of them at once by
        :func:`_crossings` (a city route passes ~70 junctions, a grid route ~170).
        ``came``/``leaves`` are (rows, at_target) per node of the road arrived on and of the
        road taken."""
        offsets, rows, bearings, entry, came_at, leaves_at = _crossings(
            self.offsets, self.row, self.at_target, self.bearing, graph.segs.oneway,
            nodes.astype(np.int64, copy=False), came[0].astype(np.int64, copy=False), came[1],
            leaves[0].astype(np.int64, copy=False), leaves[1])
        if avoid:
            entry &= ~np.isin(graph.segs.road_class[rows], list(avoid))
        return Crossings(offsets.tolist(), bearings.tolist(), entry.tolist(), came_at.tolist(),
                         leaves_at.tolist())


@kernel("Tuple((i8[:], i8[:], i8[:], b1[:], i8[:], i8[:]))(i8[:], i8[:], b1[:], i8[:], i1[:], "
        "i8[:], i8[:], b1[:], i8[:], b1[:])")
def _crossings(offsets: np.ndarray, row: np.ndarray, at_target: np.ndarray, bearing: np.ndarray,
               oneway: np.ndarray, nodes: np.ndarray, came_rows: np.ndarray,
               came_at: np.ndarray, leaves_rows: np.ndarray, leaves_at: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                          np.ndarray]:
    """The roads at each of ``nodes``, read off the index (``offsets``, ``row``, ``at_target``,
    ``bearing``, sorted by node then clockwise): where each node's roads start in the flat
    output (then the total), their rows, bearings and ``entry`` by the one-way rules (avoided
    classes are the caller's), and the index among them of the road ``came`` on and of the
    road it ``leaves`` by (-1: not there). One pass instead of ~15 numpy calls per leg, each of
    which cost more than its few hundred elements."""
    n = len(nodes)
    out_offsets = np.zeros(n + 1, np.int64)
    for k in range(n):
        out_offsets[k + 1] = out_offsets[k] + offsets[nodes[k] + 1] - offsets[nodes[k]]
    total = out_offsets[n]
    rows = np.empty(total, np.int64)
    bearings = np.empty(total, np.int64)
    entry = np.empty(total, np.bool_)
    came = np.full(n, -1, np.int64)
    leaves = np.full(n, -1, np.int64)
    for k in range(n):
        lo = offsets[nodes[k]]
        for j in range(out_offsets[k + 1] - out_offsets[k]):
            r, target, at = row[lo + j], at_target[lo + j], out_offsets[k] + j
            rows[at], bearings[at] = r, bearing[lo + j]
            entry[at] = oneway[r] <= 0 if target else oneway[r] >= 0
            if r == came_rows[k] and target == came_at[k]:
                came[k] = j
            if r == leaves_rows[k] and target == leaves_at[k]:
                leaves[k] = j
    return out_offsets, rows, bearings, entry, came, leaves


@dataclass(frozen=True)
class Crossings:
    """The roads at each joint of a leg, as flat lists cut by ``offsets``: their bearings,
    ``entry`` (may be driven into), and the index among them of the road arrived on and of the
    road taken (-1: not there)."""

    offsets: list[int]
    bearings: list[int]
    entry: list[bool]
    came: list[int]
    leaves: list[int]

    def degree(self, k: int) -> int:
        """How many segment ends meet at joint ``k``."""
        return self.offsets[k + 1] - self.offsets[k]

    def intersection(self, k: int, location: list[float]) -> dict[str, Any]:
        """OSRM's intersection object at joint ``k``."""
        a, b = self.offsets[k], self.offsets[k + 1]
        out: dict[str, Any] = {"location": location, "bearings": self.bearings[a:b],
                               "entry": self.entry[a:b]}
        if self.came[k] >= 0:
            out["in"] = self.came[k]
        if self.leaves[k] >= 0:
            out["out"] = self.leaves[k]
        return out


_cache: OrderedDict[int, Junctions] = OrderedDict()
_lock = threading.Lock()


def junctions_built(graph: RoadGraph) -> bool:
    """Whether the index of ``graph``'s shape is built (:func:`junctions` will not build it)."""
    with _lock:
        return id(graph.shape) in _cache


def junctions(graph: RoadGraph) -> Junctions:
    """The index of ``graph``'s shape (built on first use per shape)."""
    shape = graph.shape
    assert shape is not None  # set by RoadGraph itself
    with _lock:
        found = _cache.get(id(shape))
        if found is not None:
            _cache.move_to_end(id(shape))
            return found
    built = Junctions(shape)
    with _lock:
        _cache[id(shape)] = built
        while len(_cache) > KEEP:
            _cache.popitem(last=False)
    return built
