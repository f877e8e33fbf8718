"""Routes that leave the road: off-road legs over a vehicle's cost surface, joined to the road
network where the total time is least.

A leg from ``a`` to ``b`` is the faster of two answers:

- entirely off road: the least-cost path over the surface (``skimage.graph.MCP_Geometric``,
  8-connected, a move costing the mean of its two cells' seconds per metre times its
  length), searched from ``a`` until ``b`` is reached;
- off road to a road vertex ``u``, along the roads to a vertex ``v``, off road to ``b``: the
  times to every vertex come from the two searches (from ``a``, and from ``b``: costs do not
  depend on the direction of travel), each stopped at the direct time (no join beyond it
  can win), and one Dijkstra over the road graph with a virtual start joined to every ``u``
  at its off-road time and every ``v`` joined to a virtual end at its off-road time picks
  the best pair (``u``, ``v``) among all of them: the join is chosen by total time, never by
  distance to the road.

A point on a cell the vehicle cannot drive (too steep, a step, forbidden, no height) is
refused, saying which point and why; no path is ``NoRoute``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import networkx as nx
import numpy as np
from skimage.graph import MCP_Geometric

from app.errors import NoRouteError, NoSegmentError
from app.routing import params
from app.routing.geometry import haversine_m
from app.routing.profiles import OffroadSettings
from app.terrain.cost import FORBIDDEN, NODATA, STEEP, STEP
from app.terrain.roads import Roads
from app.terrain.surface import Surface

Cell = tuple[int, int]
NO_PATH = ("no off-road path joins the points over the elevation layer (slopes, steps or "
           "forbidden areas close every way)")
START, END = "start", "end"


@dataclass(frozen=True)
class Part:
    """One part of a leg: off road (its cells) or on the road (its graph nodes)."""

    offroad: bool
    coords: list[tuple[float, float]]
    seconds: float
    cells: list[Cell] | None = None  # off road
    edge_segments: list[int] | None = None  # on the road: the segment of each edge

    @property
    def segments(self) -> list[int]:
        """The segments driven, in order, each run once."""
        return [s for k, s in enumerate(self.edge_segments or [])
                if k == 0 or s != (self.edge_segments or [])[k - 1]]

    @property
    def metres(self) -> float:
        """Length along the coordinates."""
        return sum(haversine_m(a, b) for a, b in zip(self.coords[:-1], self.coords[1:],
                                                     strict=True))


def check_point(surface: Surface, roads: Roads, i: int, point: tuple[float, float],
                on_road: bool, layer: str, settings: OffroadSettings, profile: str) -> Cell:
    """The cell of input point ``i``, or ``NoSegment`` saying why the vehicle cannot start
    or end there. A point within the snap radius of a road (``on_road``) starts at the
    road vertex nearest to it, whose cell is drivable whatever the ground's slope."""
    where = f"{params.point(i)} ({point[0]:.6f},{point[1]:.6f})"
    cell = surface.grid.cell_of(*point)
    if cell is None:
        raise NoSegmentError(f"{where} is outside elevation layer {layer} and farther than "
                             "the snap radius from every road")
    joins = np.array([c for _, c in roads.joins()]).reshape(-1, 2)
    if on_road and len(joins):
        nearest = joins[np.argmin(np.hypot(*(joins - np.array(cell)).T))]
        return int(nearest[0]), int(nearest[1])
    why = surface.costs.why[cell]
    if why == STEEP:
        raise NoSegmentError(
            f"{where} is on a slope of {surface.costs.slope[cell]:.1f}°; the {profile} "
            f"profile drives at most {settings.max_slope_deg:g}° (max_slope=)")
    if why == STEP:
        raise NoSegmentError(
            f"{where} is on a step of {surface.costs.step[cell]:.2f} m; the {profile} "
            f"profile crosses at most {settings.max_step_m:g} m (max_step=)")
    if why == FORBIDDEN:
        raise NoSegmentError(f"{where} is in a forbidden area (forbid=)")
    if why == NODATA:
        raise NoSegmentError(f"{where} has no height in elevation layer {layer}")
    return cell


def _offroad(surface: Surface, mcp: MCP_Geometric, cumulative: np.ndarray, to: Cell,
             first: tuple[float, float] | None, last: tuple[float, float] | None,
             reverse: bool = False) -> Part:
    cells = [tuple(c) for c in mcp.traceback(to)]
    if reverse:
        cells = cells[::-1]
    rows, cols = np.array(cells).T
    lon, lat = surface.grid.lonlat(rows, cols)
    coords = [(float(x), float(y)) for x, y in zip(lon, lat, strict=True)]
    coords = ([first] if first else []) + coords + ([last] if last else [])
    return Part(True, coords, float(cumulative[to]), cells=cells)


def plan_leg(surface: Surface, roads: Roads, a: Cell, b: Cell, pa: tuple[float, float],
             pb: tuple[float, float]) -> list[Part]:
    """The fastest way from ``a`` to ``b`` (module docstring), as its parts in order."""
    with roads.searchers() as (mcp_a, mcp_b):
        from_a, _ = mcp_a.find_costs([a], [b])
        joins = roads.joins()
        if not joins:  # no road to join: the search from b would be wasted
            if not np.isfinite(from_a[b]):
                raise NoRouteError(NO_PATH)
            return [_offroad(surface, mcp_a, from_a, b, pa, pb)]
        from_b, _ = mcp_b.find_costs([b], [a])
        return _joined(surface, roads, joins, mcp_a, from_a, mcp_b, from_b, a, b, pa, pb)


def _joined(surface: Surface, roads: Roads, joins: list[tuple[object, Cell]],
            mcp_a: MCP_Geometric, from_a: np.ndarray, mcp_b: MCP_Geometric,
            from_b: np.ndarray, a: Cell, b: Cell, pa: tuple[float, float],
            pb: tuple[float, float]) -> list[Part]:
    direct = float(from_a[b])
    g = nx.DiGraph(roads.graph)
    for node, cell in joins:
        if from_a[cell] < direct:
            g.add_edge(START, node, seconds=float(from_a[cell]))
        if from_b[cell] < direct:
            g.add_edge(node, END, seconds=float(from_b[cell]))
    try:
        total, path = nx.single_source_dijkstra(g, START, END, weight="seconds") \
            if START in g and END in g else (np.inf, [])
    except nx.NetworkXNoPath:
        total, path = np.inf, []
    if not np.isfinite(min(direct, total)):
        raise NoRouteError(NO_PATH)
    if direct <= total:
        return [_offroad(surface, mcp_a, from_a, b, pa, pb)]
    u, v = path[1], path[-2]
    nodes = roads.graph.nodes
    road_coords = [nodes[n]["lonlat"] for n in path[1:-1]]
    segments = [roads.graph.edges[x, y]["segment"] for x, y in itertools.pairwise(path[1:-1])]
    road_seconds = total - g.edges[START, u]["seconds"] - g.edges[v, END]["seconds"]
    parts = [_offroad(surface, mcp_a, from_a, nodes[u]["cell"], pa, nodes[u]["lonlat"]),
             Part(False, road_coords, float(road_seconds), edge_segments=segments),
             _offroad(surface, mcp_b, from_b, nodes[v]["cell"], nodes[v]["lonlat"], pb,
                      reverse=True)]
    return [p for p in parts if not (p.offroad and len(p.cells or []) <= 1
                                     and p.seconds == 0 and p.metres == 0)]


def slope_profile(surface: Surface, part: Part) -> list[list[float]]:
    """``[s, z, grade %]`` along an off-road part's cells: metres from its start, height,
    and the grade of the move into the cell (0 for the first)."""
    assert part.cells is not None
    rows, cols = np.array(part.cells).T
    z = surface.heights[rows, cols].astype(np.float64)
    lon, lat = surface.grid.lonlat(rows, cols)
    step = np.array([0.0] + [haversine_m((lon[k - 1], lat[k - 1]), (lon[k], lat[k]))
                             for k in range(1, len(z))])
    grade = np.zeros(len(z))
    grade[1:] = np.diff(z) / np.maximum(step[1:], 1e-9) * 100
    return [[round(float(s), 2), round(float(h), 2), round(float(g), 1)]
            for s, h, g in zip(np.cumsum(step), z, grade, strict=True)]
