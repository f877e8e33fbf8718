"""OSRM's nearest, table, trip and match requests end to end: snap, search, shape.

Each reads the network's version once (:mod:`app.routing.reads`) and works on the graph
holding every edit committed before the request, like a route (:mod:`app.routing.planner`);
options arrive parsed and bounded (:mod:`app.routing.options`,
:mod:`app.routing.service_options`). Answers follow OSRM's response schemas, with the
segment id and fraction of every snapped point added, as routes have them.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from app.errors import NoMatchError, NoSegmentError, NoTripsError
from app.routing import engine, params
from app.routing.budget import Budget
from app.routing.costs import Cost
from app.routing.engine import Leg, Piece
from app.routing.geometry import haversine_m
from app.routing.graph import RoadGraph
from app.routing.matching import Matching, Track, match
from app.routing.nearby import within
from app.routing.optimize import trip_order
from app.routing.options import RouteOptions
from app.routing.osrm import Shaper, waypoint
from app.routing.planner import graph_at
from app.routing.reads import Reads
from app.routing.service_options import MatchOptions, NearestOptions, TableOptions, TripOptions
from app.routing.snap import fitting, network_graph, no_segment, snap_points
from app.routing.table import matrices
from app.routing.trace import location, nodes_around

# OSRM's match confidence: a Bayes classifier on log(matched length / trace length) between
# two Laplace distributions OSRM fitted to hand-classified traces (matching_confidence.hpp).
NEAREST_FIRST_M = 100.0  # nearest searches this far first, then 4x wider up to the radius
CONFIDENT = (0.005986, 0.016646, 0.696774)  # location, scale, prior
DOUBTFUL = (0.054385, 0.458432, 1 - 0.696774)


def plan_nearest(reads: Reads, network: str, point: tuple[float, float], opts: RouteOptions,
                 nearest: NearestOptions) -> dict[str, Any]:
    """The ``number`` nearest segments a vehicle at ``point`` could drive (within its radius,
    fitting its bearing and approach), nearest first, each with the ids of the vertices
    around the snapped point (OSRM's ``nodes``)."""
    graph = network_graph(reads, network, graph_at)
    snap_opts = opts.point(0)
    reach = min(NEAREST_FIRST_M, snap_opts.radius_m)
    while True:  # widening: the whole radius (10 km by default) only when the roads are sparse
        near = within(graph, np.array([point]), np.array([reach]), opts.avoid).of(0)
        look = replace(snap_opts, radius_m=reach)
        snaps = list(itertools.islice(fitting(graph, near, 0, point, look), nearest.number))
        if len(snaps) == nearest.number or reach >= snap_opts.radius_m:
            break
        reach = min(reach * 4, snap_opts.radius_m)
    if not snaps:
        raise no_segment(graph, 0, point, near, snap_opts, opts.avoid)
    return {"code": "Ok", "waypoints": [
        {**waypoint(graph, s, opts.generate_hints), "nodes": nodes_around(graph, s)}
        for s in snaps]}


def _cells(matrix: np.ndarray) -> list[list[float | None]]:
    """A matrix as OSRM writes it: to 0.1 (s or m, OSRM's precision: a 100 x 100 table of
    full doubles is 400 kB of JSON that gzip cannot shrink, costing more than computing it)
    and ``null`` where no route joins the two points."""
    return [[v if math.isfinite(v) else None for v in row]
            for row in np.round(matrix, 1).tolist()]


def plan_table(reads: Reads, network: str, points: list[tuple[float, float]],
               opts: RouteOptions, table: TableOptions) -> dict[str, Any]:
    """Durations and/or distances from every source to every destination (OSRM's table)."""
    graph, snaps = snap_points(reads, network, points, [opts.point(i) for i in range(len(points))],
                               opts.avoid, graph_at)
    cg = graph.costs(opts.cost, opts.avoid)
    places = [engine.place(graph, s) for s in snaps]
    found = matrices(graph, cg, [places[i] for i in table.sources],
                     [places[j] for j in table.destinations], table.annotations)
    body: dict[str, Any] = {"code": "Ok"}
    if table.fallback_speed is not None:
        gaps = np.argwhere(~np.isfinite(found.weight))
        ends = points if table.fallback_coordinate == "input" else \
            [(xy[0], xy[1]) for xy in (location(graph, s) for s in snaps)]
        crow = [haversine_m(ends[table.sources[i]], ends[table.destinations[j]])
                for i, j in gaps.tolist()]
        for (i, j), metres in zip(gaps.tolist(), crow, strict=True):
            if found.duration is not None:
                found.duration[i, j] = metres / table.fallback_speed
            if found.distance is not None:
                found.distance[i, j] = metres
        body["fallback_speed_cells"] = gaps.tolist()
    if found.duration is not None:
        body["durations"] = _cells(found.duration * table.scale_factor)
    if found.distance is not None:
        body["distances"] = _cells(found.distance)
    if not opts.skip_waypoints:
        body["sources"] = [waypoint(graph, snaps[i], opts.generate_hints)
                           for i in table.sources]
        body["destinations"] = [waypoint(graph, snaps[j], opts.generate_hints)
                                for j in table.destinations]
    return body


def plan_trip(reads: Reads, network: str, points: list[tuple[float, float]],
              opts: RouteOptions, trip: TripOptions) -> dict[str, Any]:
    """The cheapest order to visit every point and the route through it (OSRM's trip)."""
    graph, snaps = snap_points(reads, network, points, [opts.point(i) for i in range(len(points))],
                               opts.avoid, graph_at)
    cg = graph.costs(opts.cost, opts.avoid)
    router = engine.Router(graph, cg, snaps)
    weight = matrices(graph, cg, router.places, router.places).weight
    if not np.isfinite(weight).all():
        i, j = (int(k) for k in np.argwhere(~np.isfinite(weight))[0])
        raise NoTripsError(f"no trip visits every point: no route leads from "
                           f"{params.point(i)} to {params.point(j)}")
    order = trip_order(weight, trip.roundtrip, trip.fixed_start, trip.fixed_end)
    legs = router.legs([*order, order[0]] if trip.roundtrip else order)
    body: dict[str, Any] = {"code": "Ok", "trips": Shaper(graph, opts).routes([legs])}
    if not opts.skip_waypoints:
        rank = {point: k for k, point in enumerate(order)}
        body["waypoints"] = [{**waypoint(graph, s, opts.generate_hints), "trips_index": 0,
                              "waypoint_index": rank[s.index]} for s in snaps]
    return body


def confidence(trace_m: float, matched_m: float) -> float:
    """OSRM's confidence that a matching is right, 0..1, from how much longer or shorter
    the matched route is than the trace."""
    if trace_m <= 0 or matched_m <= 0:
        return 0.0
    x = math.log(matched_m / trace_m)
    ok, bad = ((prior / (2 * scale)) * math.exp(-abs(x - loc) / scale)
               for loc, scale, prior in (CONFIDENT, DOUBTFUL))
    return ok / (ok + bad)


def _joined(legs: Sequence[Leg]) -> Leg:
    """Consecutive legs as one (a leg through points that are not waypoints): the pieces
    that meet mid-segment, driven the same way, become one piece."""
    pieces: list[Piece] = []
    for leg in legs:
        for p in leg.pieces:
            last = pieces[-1] if pieces else None
            if last is not None and last.row == p.row and last.f_to == p.f_from and \
                    (last.f_to >= last.f_from) == (p.f_to >= p.f_from):
                pieces[-1] = Piece(p.row, last.f_from, p.f_to)
            else:
                pieces.append(p)
    return Leg.of(legs[0].start, legs[-1].end, sum(leg.weight for leg in legs), pieces)


def _legs(router: engine.Router, m: Matching, waypoints: set[int] | None,
          budget: Budget) -> list[Leg]:
    """A matching's legs between consecutive matched points, joined between waypoints."""
    steps = []
    for a, b in itertools.pairwise(range(len(m.points))):
        budget.check()
        steps.append(router.leg(a, b))
    if waypoints is None:
        return steps
    ends = [k for k, i in enumerate(m.points)
            if i in waypoints or k in (0, len(m.points) - 1)]
    return [_joined(steps[a:b]) for a, b in itertools.pairwise(ends)]


def plan_match(reads: Reads, network: str, points: list[tuple[float, float]],
               opts: RouteOptions, options: MatchOptions) -> dict[str, Any]:
    """The roads the trace drove (OSRM's match): ``matchings`` (routes, each with its
    ``confidence``) and one ``tracepoint`` per input point (``null`` where it was left out)."""
    graph = network_graph(reads, network, graph_at)
    trace = Track(points, opts.points, options.timestamps, options.gaps == "split", options.tidy)
    budget = Budget("matching", "send a shorter trace")
    found = match(graph, graph.costs(Cost.DISTANCE, opts.avoid), trace, opts.avoid, budget)
    if not found:
        raise _unmatched(graph, trace, opts)
    cg = graph.costs(opts.cost, opts.avoid)
    chosen = set(options.waypoints) if options.waypoints is not None else None
    routes, tracepoints = [], [None] * len(points)  # type: list[list[Leg]], list[Any]
    for m_index, m in enumerate(found):
        routes.append(_legs(engine.Router(graph, cg, m.snaps), m, chosen, budget))
        ranks = [i for k, i in enumerate(m.points)
                 if chosen is None or i in chosen or k in (0, len(m.points) - 1)]
        rank = {i: k for k, i in enumerate(ranks)}
        for snap, alternatives in zip(m.snaps, m.alternatives, strict=True):
            tracepoints[snap.index] = {
                **waypoint(graph, snap, opts.generate_hints), "matchings_index": m_index,
                "waypoint_index": rank.get(snap.index), "alternatives_count": alternatives}
    matchings = Shaper(graph, opts, budget).routes(routes)
    for m, shaped in zip(found, matchings, strict=True):
        driven = sum(haversine_m(points[a], points[b]) for a, b in itertools.pairwise(m.points))
        shaped["confidence"] = confidence(driven, shaped["distance"])
    body: dict[str, Any] = {"code": "Ok", "matchings": matchings}
    if not opts.skip_waypoints:
        body["tracepoints"] = tracepoints
    return body


def _unmatched(graph: RoadGraph, trace: Track, opts: RouteOptions) -> Exception:
    """Why nothing matched: no point near a road (``NoSegment``), or no two consecutive
    points joined by one (``NoMatch``)."""
    sigma = np.array([o.radius_m for o in trace.snap])
    near = within(graph, np.array(trace.points), 3 * sigma, opts.avoid)
    if not len(near):
        return NoSegmentError(f"no point of the trace lies within 3 GPS standard deviations "
                              f"({3 * sigma.min():g} m or more) of a road")
    return NoMatchError("no two consecutive points of the trace could be matched to roads "
                        "joining them: the trace is too sparse or far from the network")
