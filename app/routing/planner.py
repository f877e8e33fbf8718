"""One route request end to end: parse, snap, fetch the current graph, order, search, shape.

Shared by the HTTP router and the CLI so both answer identically.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from sqlalchemy import Connection

from app.db.session import get_engine
from app.errors import InvalidQueryError, TooBigError
from app.routing import engine
from app.routing.costs import Cost
from app.routing.graph import CostGraph, RoadGraph
from app.routing.isochrone import isochrone_geojson
from app.routing.live import registry
from app.routing.optimize import best_order
from app.routing.osrm import Shaper
from app.routing.settings import routing_settings
from app.routing.snap import Snapped, snap_points
from app.routing.waypoints import dense_waypoints
from app.settings import get_settings

GEOMETRIES = ("geojson", "polyline")
FORMATS = ("osrm", "waypoints")


def parse_points(raw: str) -> list[tuple[float, float]]:
    """``lon,lat;lon,lat;...`` -> [(lon, lat), ...]; 400 naming the first bad point."""
    points = []
    for i, part in enumerate(raw.strip().strip(";").split(";")):
        try:
            lon, lat = (float(v) for v in part.split(","))
        except ValueError:
            raise InvalidQueryError(f"point {i} {part!r} is not 'lon,lat'") from None
        points.append(check_point(i, lon, lat))
    return points


def check_point(i: int, lon: float, lat: float) -> tuple[float, float]:
    """The point, or 400 naming it when it is not a finite lon/lat."""
    if not (math.isfinite(lon) and math.isfinite(lat) and -180 <= lon <= 180
            and -90 <= lat <= 90):
        raise InvalidQueryError(f"point {i} ({lon},{lat}) is outside lon -180..180, lat -90..90")
    return lon, lat


@dataclass
class RouteOptions:
    """A route request's options, shared by the query string, the POST body and the CLI."""
    cost: Cost = Cost.TIME
    avoid: frozenset[str] = field(default_factory=frozenset)
    optimize: bool = False
    geometries: str = "geojson"
    format: str = "osrm"
    spacing_m: float = 1.0
    radius_m: float | None = None

    def check(self, n_points: int) -> None:
        """Refuse requests outside the limits before any search starts."""
        limits = routing_settings()
        if n_points < 2:
            raise InvalidQueryError("a route needs at least two points")
        if n_points > limits.max_points:
            raise TooBigError(f"{n_points} points; at most {limits.max_points} per route")
        if self.optimize and n_points > limits.max_optimize_points:
            raise TooBigError(f"{n_points} points; optimize=true takes at most "
                         f"{limits.max_optimize_points}")
        if self.geometries not in GEOMETRIES:
            raise InvalidQueryError(f"geometries must be one of {', '.join(GEOMETRIES)}")
        if self.format not in FORMATS:
            raise InvalidQueryError(f"format must be one of {', '.join(FORMATS)}")
        if not (self.spacing_m >= limits.min_spacing_m):
            raise InvalidQueryError(f"spacing must be at least {limits.min_spacing_m} m")
        if self.radius_m is not None and not self.radius_m > 0:
            raise InvalidQueryError("radius must be positive")


@contextmanager
def read_connection() -> Iterator[Connection]:
    """An autocommit connection for the snap query: one read-only statement needs no
    BEGIN/COMMIT round trips (they cost more than the route search on small networks)."""
    with get_engine().connect() as conn:
        yield conn.execution_options(isolation_level="AUTOCOMMIT")


def current_graph(conn: Connection, network: str, points: list[tuple[float, float]],
                  avoid: frozenset[str], radius_m: float | None
                  ) -> tuple[Snapped, RoadGraph]:
    """Snap the points and return the graph containing every edit the snap could see."""
    radius = radius_m if radius_m is not None else routing_settings().snap_radius_m
    snapped = snap_points(conn, network, points, radius, avoid)
    graph = registry(get_settings().database_url).get(snapped.network_id, snapped.version)
    return snapped, graph


def visit_order(router: engine.Router, n: int) -> list[int]:
    """The best visiting order of the points (first and last fixed) from their cost matrix."""
    matrix = np.array([router.costs_from(i, range(n)) for i in range(n)])
    return best_order(matrix)


def plan_route(conn: Connection, network: str, points: list[tuple[float, float]],
               opts: RouteOptions) -> dict[str, Any]:
    """Snap the points, search the graph that contains every edit the snap saw, and shape the OSRM
    (or waypoints) response."""
    opts.check(len(points))
    snapped, graph = current_graph(conn, network, points, opts.avoid, opts.radius_m)
    cg: CostGraph = graph.costs(opts.cost, opts.avoid)
    router = engine.Router(graph, cg, snapped.snaps)
    order = visit_order(router, len(points)) if opts.optimize and len(points) > 2 else None
    seq = order or list(range(len(points)))
    legs = [router.leg(i, j) for i, j in itertools.pairwise(seq)]
    shaper = Shaper(graph, opts.geometries)
    if opts.format == "waypoints":
        return {"code": "Ok", **dense_waypoints(shaper, legs, opts.spacing_m),
                "order": seq}
    return shaper.response(legs, opts.cost, snapped.snaps, order)


def plan_isochrone(conn: Connection, network: str, point: tuple[float, float],
                   seconds: float | None, meters: float | None, avoid: frozenset[str],
                   radius_m: float | None) -> dict[str, Any]:
    """GeoJSON of what is reachable from ``point`` within ``seconds`` or ``meters``."""
    limits = routing_settings()
    if seconds is not None and meters is None:
        budget, most, cost, unit = seconds, limits.max_isochrone_seconds, Cost.TIME, "s"
    elif meters is not None and seconds is None:
        budget, most, cost, unit = meters, limits.max_isochrone_meters, Cost.DISTANCE, "m"
    else:
        raise InvalidQueryError("give exactly one of seconds= or meters=")
    if not 0 < budget <= most:
        raise InvalidQueryError(f"the budget must be in (0, {most:g}]")
    snapped, graph = current_graph(conn, network, [point], avoid, radius_m)
    return isochrone_geojson(graph, graph.costs(cost, avoid), snapped.snaps[0], avoid, budget,
                             unit)
