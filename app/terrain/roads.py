"""The road network where an off-road leg may join it: a small networkx graph of the
segments over a cost surface, with the cell under each vertex.

Joins happen at road vertices, densified to one every two cells, so a join is never more
than a cell from the best place along a segment. A vertex's cell is made drivable at the
vehicle's flat speed (a road cut into a slope steeper than the vehicle climbs off road is
still a road it can leave or reach); vertices two cells apart never form a chain of
adjacent cells, so this opens no off-road corridor along the road.
"""

from __future__ import annotations

import itertools
import math
import queue
import threading
from collections import OrderedDict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import networkx as nx
import numpy as np
from skimage.graph import MCP_Geometric

from app.routing.geometry import haversine_m
from app.routing.graph import RoadGraph
from app.terrain.surface import TO_4326, Surface

CACHED = 4


@dataclass(frozen=True)
class Roads:
    """The road graph over a surface: nodes are ``("n", node id)`` for segment ends and
    ``("v", row, k)`` for vertices between them, each with ``lonlat``, ``cell`` (or None
    outside the surface) and ``segment`` (the id of a segment it lies on); edges carry
    ``seconds``, ``metres`` and ``segment``. ``cost`` is the surface's cost with the
    vertices' cells drivable; ``cell_m`` its cells' ground size."""

    graph: nx.DiGraph
    cost: np.ndarray
    cell_m: float
    _idle: queue.SimpleQueue = field(default_factory=queue.SimpleQueue, compare=False)

    @contextmanager
    def searchers(self) -> Iterator[tuple[MCP_Geometric, MCP_Geometric]]:
        """Two least-cost searchers over :attr:`cost` (one from each end of a leg), lent for
        one leg. Building one costs as much as a third of a search on a survey-sized grid
        (0.2 s at 1.5 M cells), and a searcher may search again from other cells, so they
        are kept and reused; one pair per concurrent leg, as a searcher holds its last
        search for the traceback."""
        try:
            pair = self._idle.get_nowait()
        except queue.Empty:
            pair = tuple(MCP_Geometric(self.cost, fully_connected=True,
                                       sampling=(self.cell_m, self.cell_m)) for _ in range(2))
        try:
            yield pair
        finally:
            self._idle.put(pair)

    def joins(self) -> list[tuple[object, tuple[int, int]]]:
        """Every node inside the surface, with its cell."""
        return [(n, d["cell"]) for n, d in self.graph.nodes(data=True) if d["cell"] is not None]


def _densified(coords: np.ndarray, spacing_m: float) -> np.ndarray:
    out = [coords[0]]
    for a, b in itertools.pairwise(coords):
        n = max(1, math.ceil(haversine_m(tuple(a), tuple(b)) / spacing_m))
        out.extend(a + (b - a) * (k / n) for k in range(1, n + 1))
    return np.array(out)


def build_roads(road_graph: RoadGraph, surface: Surface, avoid: frozenset[str],
                flat_cost: float) -> Roads:
    """The road graph of the segments of ``road_graph`` meeting ``surface`` (classes in
    ``avoid`` left out), and the cost with its vertices' cells drivable at ``flat_cost``."""
    grid = surface.grid
    west, south = TO_4326.transform(grid.bbox[0], grid.bbox[1])
    east, north = TO_4326.transform(grid.bbox[2], grid.bbox[3])
    s = road_graph.segs
    boxes = s.bboxes()
    meets = ((boxes[:, 0] <= east) & (boxes[:, 2] >= west) & (boxes[:, 1] <= north)
             & (boxes[:, 3] >= south))
    g = nx.DiGraph()
    cost = surface.costs.cost.copy()
    spacing = 2 * grid.cell_m
    for r in np.flatnonzero(meets):
        if s.road_class[r] in avoid:
            continue
        coords = _densified(s.coords[s.offsets[r]:s.offsets[r + 1]], spacing)
        keys = [("n", int(s.source[r])), *[("v", int(r), k) for k in range(1, len(coords) - 1)],
                ("n", int(s.target[r]))]
        speed = float(road_graph.speed_kph[r]) / 3.6
        for key, (lon, lat) in zip(keys, coords, strict=True):
            cell = grid.cell_of(float(lon), float(lat))
            g.add_node(key, lonlat=(float(lon), float(lat)), cell=cell, segment=int(s.ids[r]))
            if cell is not None:
                cost[cell] = min(cost[cell], flat_cost)
        for (ka, a), (kb, b) in zip(zip(keys[:-1], coords[:-1], strict=True),
                                    zip(keys[1:], coords[1:], strict=True), strict=True):
            metres = haversine_m(tuple(a), tuple(b))
            edge = {"seconds": metres / speed, "metres": metres, "segment": int(s.ids[r])}
            if s.oneway[r] >= 0:
                g.add_edge(ka, kb, **edge)
            if s.oneway[r] <= 0:
                g.add_edge(kb, ka, **edge)
    return Roads(g, cost, grid.cell_m)


_cache: OrderedDict[tuple, Roads] = OrderedDict()
_lock = threading.Lock()


def roads_over(road_graph: RoadGraph, surface: Surface, avoid: frozenset[str],
               flat_cost: float) -> Roads:
    """:func:`build_roads`, kept per (network version, surface, avoided classes)."""
    key = (road_graph.network_id, road_graph.version, surface.key, avoid, flat_cost)
    with _lock:
        found = _cache.get(key)
        if found is not None:
            _cache.move_to_end(key)
            return found
    made = build_roads(road_graph, surface, avoid, flat_cost)
    with _lock:
        _cache[key] = made
        while len(_cache) > CACHED:
            _cache.popitem(last=False)
    return made
