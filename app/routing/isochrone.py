"""Service area: which parts of the network are reachable from a point within a budget.

One bounded Dijkstra (scipy's ``limit``) from the snapped point gives the cost to every node
within budget; each segment leaving a reached node in an allowed direction is reachable up to
the fraction the remaining budget pays for. Pieces of the same segment reached from both ends
(or from the start point) are merged.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import numpy as np

from app.errors import ResponseTooLargeError
from app.routing import engine
from app.routing.budget import Budget
from app.routing.geometry import cut
from app.routing.graph import CostGraph, RoadGraph
from app.routing.settings import routing_settings
from app.routing.snap import Snap


def _merge(intervals: list[tuple[float, float]]) -> list[tuple[float, float]]:
    merged: list[list[float]] = []
    for lo, hi in sorted(intervals):
        if merged and lo <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], hi)
        else:
            merged.append([lo, hi])
    return [(lo, hi) for lo, hi in merged]


def reachable(graph: RoadGraph, cg: CostGraph, snap: Snap, avoid: frozenset[str],
              budget: float) -> dict[int, list[tuple[float, float]]]:
    """Segment row -> reachable fraction intervals."""
    start = engine.place(graph, snap)
    deps = engine.departures(graph, cg, start)
    dist, _ = cg.search(((n, c) for n, c, _ in deps), limit=budget)
    dist = dist[: graph.n_nodes]
    s, c = graph.segs, cg.seg_cost
    usable = ~np.isin(s.road_class, list(avoid)) if avoid else np.ones(len(s), bool)
    out: dict[int, list[tuple[float, float]]] = defaultdict(list)
    with np.errstate(divide="ignore", invalid="ignore"):
        reach_u = np.where(c > 0, (budget - dist[graph.u]) / c, np.inf)
        reach_v = np.where(c > 0, (budget - dist[graph.v]) / c, np.inf)
    fwd = np.flatnonzero(usable & (s.oneway >= 0) & (dist[graph.u] <= budget))
    bwd = np.flatnonzero(usable & (s.oneway <= 0) & (dist[graph.v] <= budget))
    for r in fwd:
        out[int(r)].append((0.0, float(min(1.0, reach_u[r]))))
    for r in bwd:
        out[int(r)].append((float(max(0.0, 1.0 - reach_v[r])), 1.0))
    if start.at_node is None:  # the start segment, from the start point itself
        reach = budget / c[start.row] if c[start.row] > 0 else np.inf
        f, way = start.fraction, int(s.oneway[start.row])
        if way >= 0:
            out[start.row].append((f, float(min(1.0, f + reach))))
        if way <= 0:
            out[start.row].append((float(max(0.0, f - reach)), f))
    return {r: _merge(iv) for r, iv in out.items()}


def isochrone_geojson(graph: RoadGraph, cg: CostGraph, snap: Snap, avoid: frozenset[str],
                      budget: float, unit: str) -> dict[str, Any]:
    """The reachable segments and segment parts as a GeoJSON FeatureCollection: each names its
    segment and the fraction range reached, so a client can tell whole segments from parts.
    ``TooBig`` once the request's time budget is spent."""
    time_left = Budget("the isochrone", "ask for a smaller budget or another point")
    reached = reachable(graph, cg, snap, avoid, budget)
    offsets = graph.segs.offsets
    count = sum((int(offsets[r + 1] - offsets[r]) + 2) * len(iv) for r, iv in reached.items())
    most = routing_settings().max_response_coordinates
    if count > most:
        raise ResponseTooLargeError(
            f"the isochrone would hold about {count} coordinates; at most {most} "
            "(UGVMAP_ROUTING_MAX_RESPONSE_COORDINATES): ask for a smaller budget")
    features = []
    for row, intervals in sorted(reached.items()):
        time_left.check()
        coords, fracs = graph.line(row)
        for lo, hi in intervals:
            features.append({
                "type": "Feature",
                "geometry": {"type": "LineString", "coordinates": cut(coords, fracs, lo, hi)},
                "properties": {"segment_id": int(graph.segs.ids[row]), "from_fraction": lo,
                               "to_fraction": hi, "complete": lo == 0.0 and hi == 1.0},
            })
    return {"type": "FeatureCollection", "features": features,
            "properties": {"budget": budget, "unit": unit, "segment_id": snap.segment_id,
                           "snap_distance_m": snap.distance_m}}
