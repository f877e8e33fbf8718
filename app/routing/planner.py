"""One route request end to end: snap, fetch the current graph, order, search, shape.

Shared by the HTTP router and the CLI so both answer identically. Options arrive parsed and
bounded (:mod:`app.routing.options`).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
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


class TagCache:
    """Guidance tags already read, per network version (a version holds every edit, so its
    tags never go stale): routes planned again over the same roads skip the query."""

    VERSIONS = 2
    MAX_SEGMENTS = 200_000  # per version; beyond, the version starts afresh

    def __init__(self) -> None:
        self._known: OrderedDict[tuple[int, int], dict[int, RoadTags | None]] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, conn: Connection, graph: RoadGraph, ids: set[int]) -> dict[int, RoadTags]:
        """Tags of the segments ``ids`` that have any, reading only those not seen yet."""
        key = (graph.network_id, graph.version)
        with self._lock:
            known = self._known.setdefault(key, {})
            self._known.move_to_end(key)
            while len(self._known) > self.VERSIONS:
                self._known.popitem(last=False)
            have = {i: known[i] for i in ids if i in known}
        missing = sorted(ids - have.keys())
        if missing:
            rows = cast(list[tuple[int, str | None, str | None]],
                        conn.execute(TAGS_SQL, {"ids": missing}).all())
            found: dict[int, RoadTags | None] = dict.fromkeys(missing)
            found.update({int(sid): RoadTags(ref or "", junction in ROUNDABOUT)
                          for sid, ref, junction in rows if ref or junction in ROUNDABOUT})
            have.update(found)
            with self._lock:
                if len(known) + len(found) > self.MAX_SEGMENTS:
                    known.clear()
                known.update(found)
        return {i: t for i, t in have.items() if t is not None}


_tags = TagCache()


def road_tags(conn: Connection, graph: RoadGraph, routes: Sequence[Sequence[Leg]]
              ) -> dict[int, RoadTags]:
    """``ref`` and roundabout flags of the segments the routes drive (OSM tags kept in
    ``attrs``, which the routing graph does not load): one indexed read of the segments not
    seen before in this network version, only for steps."""
    return _tags.get(conn, graph, {int(graph.segs.ids[p.row]) for legs in routes
                                   for leg in legs for p in leg.pieces})


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
