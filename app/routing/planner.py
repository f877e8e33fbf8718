"""One route request end to end: snap, fetch the current graph, order, search, shape.

Shared by the HTTP router and the CLI so both answer identically. Options arrive parsed and
bounded (:mod:`app.routing.options`).
"""

from __future__ import annotations

from typing import Any

from app.db.session import get_engine
from app.routing import engine
from app.routing.alternatives import alternatives
from app.routing.engine import Leg
from app.routing.graph import RoadGraph
from app.routing.isochrone import isochrone_geojson
from app.routing.junctions import junctions_built
from app.routing.live import registry
from app.routing.optimize import best_order
from app.routing.options import IsochroneOptions, RouteOptions
from app.routing.osrm import Shaper
from app.routing.reads import Reads
from app.routing.snap import Snap, snap_points
from app.routing.table import matrices
from app.routing.waypoints import dense_waypoints
from app.settings import get_settings
from app.terrain.route import add_heights, plan_offroad_route

# A route is quick (answered on the event loop, without a worker thread: app.routing.router)
# when it is a few points on a network whose longest route is shaped in a few milliseconds,
# and everything it needs is built: the graph at the version read, the snapping index, the
# cost model, the junctions for steps, and a search that is the hierarchy's or a Dijkstra
# over a small network (~1 ms at 3k segments, tens of ms at 100k).
QUICK_MAX_POINTS = 3
QUICK_MAX_SEGMENTS = 200_000
QUICK_DIJKSTRA_SEGMENTS = 10_000


def graph_at(network_id: int, version: int) -> RoadGraph:
    """This process's graph of a network, holding at least ``version``."""
    return registry(get_settings().database_url).get(network_id, version)


def current_graph(network_id: int, version: int) -> RoadGraph | None:
    """:func:`graph_at` if it needs no wait and no load, else ``None``."""
    return registry(get_settings().database_url).current(network_id, version)


def quick_route(graph: RoadGraph, n_points: int, opts: RouteOptions) -> bool:
    """Whether :func:`plan_route` answers in a few milliseconds on ``graph`` (see
    :data:`QUICK_MAX_POINTS`): no alternatives, optimisation or straight-on constraint, which
    run several searches, and the OSRM answer (dense waypoints may be many)."""
    if (n_points > QUICK_MAX_POINTS or opts.alternatives or opts.optimize
            or opts.continue_straight or opts.format != "osrm" or opts.offroad is not None
            or len(graph.segs) > QUICK_MAX_SEGMENTS):
        return False
    cg = graph.built(opts.cost, opts.avoid)
    return (cg is not None and (not opts.steps or junctions_built(graph))
            and (len(graph.segs) <= QUICK_DIJKSTRA_SEGMENTS or cg.answers_fast()))


def visit_order(router: engine.Router) -> list[int]:
    """The best visiting order of the points (first and last fixed) from their cost matrix:
    the same order a trip with ``roundtrip=false&source=first&destination=last`` takes."""
    return best_order(matrices(router.graph, router.cg, router.places, router.places).weight)


def plan_route(reads: Reads, network: str, points: list[tuple[float, float]],
               opts: RouteOptions) -> dict[str, Any]:
    """Snap the points, search the graph that contains every edit the snap saw, and shape the OSRM
    (or waypoints) response. With ``offroad=true``, points far from every road get off-road
    legs (:mod:`app.terrain.route`); when none is, the road route's waypoints get heights."""
    opts.check(len(points))
    if opts.offroad is not None:
        offroad = plan_offroad_route(reads, network, points, opts, graph_at)
        if offroad is not None:
            return offroad
    n = len(points)
    graph, snaps = snap_points(reads, network, points, [opts.point(i) for i in range(n)],
                               opts.avoid, graph_at)
    cg = graph.costs(opts.cost, opts.avoid)
    router = engine.Router(graph, cg, snaps)
    order = visit_order(router) if opts.optimize and n > 2 else None
    seq = order or list(range(n))
    legs = router.legs(seq, opts.continue_straight)
    if opts.format == "waypoints":
        dense = dense_waypoints(graph, legs, opts.spacing_m)
        if opts.offroad is not None:
            with get_engine().connect() as conn:
                add_heights(conn, opts.offroad.elevation, dense["points"])
        return {"code": "Ok", **dense, "order": seq}
    routes: list[list[Leg]] = [legs]
    if opts.alternatives and n == 2:
        routes += [[alt] for alt in alternatives(graph, cg, snaps, legs[0], opts.alternatives)]
    return Shaper(graph, opts).response(routes, snaps, order)


def plan_isochrone(reads: Reads, network: str, opts: IsochroneOptions) -> dict[str, Any]:
    """GeoJSON of what is reachable from the point within the budget."""
    graph, snaps = snap_points(reads, network, [opts.point], [opts.snap], opts.avoid, graph_at)
    snap: Snap = snaps[0]
    return isochrone_geojson(graph, graph.costs(opts.cost, opts.avoid), snap, opts.avoid,
                             opts.budget, opts.unit)
