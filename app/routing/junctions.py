"""Which roads meet at each node of a graph, for OSRM's step ``intersections`` and exit counts.

An index over the segment ends sorted by node (one argsort per graph version, built only when
a request asks for steps, and kept for the few most recent versions): each node's roads with
the bearing pointing away from the node along the road, and whether a vehicle may leave the
node along it (one-way rules; avoided classes are applied per request).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.routing.graph import RoadGraph

KEEP = 2  # graph versions whose index is kept (each ~9 bytes per segment end)


@dataclass(frozen=True)
class Road:
    """One road at a node: the segment row, whether the node is its target end, and the bearing
    pointing away from the node along it."""

    row: int
    at_target: bool
    bearing: float


class Junctions:
    """Roads per node of one graph."""

    def __init__(self, graph: RoadGraph) -> None:
        self.graph = graph
        m = len(graph.segs)
        ends = np.concatenate([graph.u, graph.v])
        order = np.argsort(ends, kind="stable")
        self.row = (order % max(m, 1)).astype(np.int32)
        self.at_target = order >= m
        away = np.where(self.at_target, (graph.bearing_end[self.row] + 180.0) % 360.0,
                        graph.bearing_start[self.row])
        self.bearing = away.astype(np.float32)
        self.offsets = np.searchsorted(ends[order], np.arange(graph.n_nodes + 1))

    def roads(self, node: int) -> list[Road]:
        """The roads at ``node`` (a graph node index), clockwise from north."""
        lo, hi = int(self.offsets[node]), int(self.offsets[node + 1])
        out = [Road(int(self.row[k]), bool(self.at_target[k]), float(self.bearing[k]))
               for k in range(lo, hi)]
        return sorted(out, key=lambda r: (round(r.bearing) % 360, r.row, r.at_target))

    def enterable(self, road: Road, avoid: frozenset[str]) -> bool:
        """May a vehicle leave the node along this road (one-way rules, avoided classes)?"""
        s = self.graph.segs
        way = int(s.oneway[road.row])
        if str(s.road_class[road.row]) in avoid:
            return False
        return way <= 0 if road.at_target else way >= 0

    def intersection(self, node: int, location: list[float], came: tuple[int, bool] | None,
                     leaves: tuple[int, bool] | None, avoid: frozenset[str]) -> dict[str, Any]:
        """OSRM's intersection object at ``node``: ``came``/``leaves`` are (row, at_target) of the
        road arrived on and the road taken."""
        roads = self.roads(node)
        keys = [(r.row, r.at_target) for r in roads]
        out: dict[str, Any] = {
            "location": location,
            "bearings": [round(r.bearing) % 360 for r in roads],
            "entry": [self.enterable(r, avoid) for r in roads],
        }
        if came is not None and came in keys:
            out["in"] = keys.index(came)
        if leaves is not None and leaves in keys:
            out["out"] = keys.index(leaves)
        return out


_cache: OrderedDict[tuple[int, int, int], Junctions] = OrderedDict()
_lock = threading.Lock()


def junctions(graph: RoadGraph) -> Junctions:
    """The index of ``graph`` (built on first use per graph version)."""
    key = (graph.network_id, graph.version, id(graph.segs))
    with _lock:
        found = _cache.get(key)
        if found is not None:
            _cache.move_to_end(key)
            return found
    built = Junctions(graph)
    with _lock:
        _cache[key] = built
        while len(_cache) > KEEP:
            _cache.popitem(last=False)
    return built
