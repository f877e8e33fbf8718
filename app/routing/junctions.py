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

    def degree(self, node: int) -> int:
        """How many segment ends meet at ``node``."""
        return int(self.offsets[node + 1] - self.offsets[node])

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

    def intersection(self, graph: RoadGraph, node: int, location: list[float],
                     came: tuple[int, bool] | None, leaves: tuple[int, bool] | None,
                     avoid: frozenset[str]) -> dict[str, Any]:
        """OSRM's intersection object at ``node``: ``came``/``leaves`` are (row, at_target) of the
        road arrived on and the road taken."""
        rows, at_target, bearings = self._at(node)
        oneway, road_class = graph.segs.oneway, graph.segs.road_class
        entry = [(oneway[r] <= 0 if t else oneway[r] >= 0)
                 and not (avoid and str(road_class[r]) in avoid)
                 for r, t in zip(rows, at_target, strict=True)]
        out: dict[str, Any] = {"location": location, "bearings": bearings,
                               "entry": [bool(e) for e in entry]}
        keys = list(zip(rows, at_target, strict=True))
        if came is not None and came in keys:
            out["in"] = keys.index(came)
        if leaves is not None and leaves in keys:
            out["out"] = keys.index(leaves)
        return out


_cache: OrderedDict[int, Junctions] = OrderedDict()
_lock = threading.Lock()


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
