"""One route request end to end: snap, fetch the current graph, order, search, shape.

Shared by the HTTP router and the CLI so both answer identically. Options arrive parsed and
bounded (:mod:`app.routing.options`).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any, cast

import numpy as np
from sqlalchemy import Connection, text

from app.db.session import get_engine
from app.routing import engine
from app.routing.alternatives import alternatives
from app.routing.engine import Leg
from app.routing.graph import RoadGraph
from app.routing.isochrone import isochrone_geojson
from app.routing.live import registry
from app.routing.optimize import best_order
from app.routing.options import IsochroneOptions, RouteOptions
from app.routing.osrm import Shaper
from app.routing.snap import Snap, snap_points
from app.routing.steps import RoadTags
from app.routing.waypoints import dense_waypoints
from app.settings import get_settings

ROUNDABOUT = ("roundabout", "circular")
TAGS_SQL = text("SELECT id, attrs->>'ref', attrs->>'junction' FROM road_segments "
                "WHERE id = ANY(CAST(:ids AS bigint[]))")


@contextmanager
def read_connection() -> Iterator[Connection]:
    """An autocommit connection for the snap query: one read-only statement needs no
    BEGIN/COMMIT round trips (they cost more than the route search on small networks)."""
    with get_engine().connect() as conn:
        yield conn.execution_options(isolation_level="AUTOCOMMIT")


def _graph_at(network_id: int, version: int) -> RoadGraph:
    return registry(get_settings().database_url).get(network_id, version)


def visit_order(router: engine.Router, n: int) -> list[int]:
    """The best visiting order of the points (first and last fixed) from their cost matrix."""
    matrix = np.array([router.costs_from(i, range(n)) for i in range(n)])
    return best_order(matrix)


def road_tags(conn: Connection, graph: RoadGraph, routes: Sequence[Sequence[Leg]]
              ) -> dict[int, RoadTags]:
    """``ref`` and roundabout flags of the segments the routes drive (OSM tags kept in
    ``attrs``, which the routing graph does not load): one indexed read, only for steps."""
    ids = sorted({int(graph.segs.ids[p.row]) for legs in routes for leg in legs
                  for p in leg.pieces})
    if not ids:
        return {}
    rows = cast(list[tuple[int, str | None, str | None]],
                conn.execute(TAGS_SQL, {"ids": ids}).all())
    return {int(sid): RoadTags(ref or "", junction in ROUNDABOUT)
            for sid, ref, junction in rows if ref or junction in ROUNDABOUT}


def plan_route(conn: Connection, network: str, points: list[tuple[float, float]],
               opts: RouteOptions) -> dict[str, Any]:
    """Snap the points, search the graph that contains every edit the snap saw, and shape the OSRM
    (or waypoints) response."""
    opts.check(len(points))
    n = len(points)
    graph, snaps = snap_points(conn, network, points, [opts.point(i) for i in range(n)],
                               opts.avoid, _graph_at)
    cg = graph.costs(opts.cost, opts.avoid)
    router = engine.Router(graph, cg, snaps)
    order = visit_order(router, n) if opts.optimize and n > 2 else None
    seq = order or list(range(n))
    legs = router.legs(seq, opts.continue_straight)
    if opts.format == "waypoints":
        return {"code": "Ok", **dense_waypoints(graph, legs, opts.spacing_m), "order": seq}
    routes: list[list[Leg]] = [legs]
    if opts.alternatives and n == 2:
        routes += [[alt] for alt in alternatives(graph, cg, snaps, legs[0], opts.alternatives)]
    tags = road_tags(conn, graph, routes) if opts.steps else None
    return Shaper(graph, opts, tags).response(routes, snaps, order)


def plan_isochrone(conn: Connection, network: str, opts: IsochroneOptions) -> dict[str, Any]:
    """GeoJSON of what is reachable from the point within the budget."""
    graph, snaps = snap_points(conn, network, [opts.point], [opts.snap], opts.avoid, _graph_at)
    snap: Snap = snaps[0]
    return isochrone_geojson(graph, graph.costs(opts.cost, opts.avoid), snap, opts.avoid,
                             opts.budget, opts.unit)
