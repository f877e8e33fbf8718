"""HTTP endpoints: ``/networks/{name}/route`` (GET and POST) and ``/networks/{name}/isochrone``.

Responses follow the OSRM route service; errors are ``{"code", "message"}`` with OSRM codes
(``InvalidQuery``, ``TooBig``, ``NoSegment``, ``NoRoute``) and ``NotFound`` for an unknown
network. Handlers are plain ``def``: the search is CPU-bound and runs in the thread pool.
"""

from __future__ import annotations

from typing import Annotated, Any

import orjson
from fastapi import APIRouter, Depends, FastAPI, Query, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field
from sqlalchemy import Connection

from app.routing.costs import Cost
from app.routing.errors import InvalidQueryError, RoutingError
from app.routing.isochrone import isochrone_geojson
from app.routing.planner import (
    RouteOptions,
    check_point,
    current_graph,
    parse_points,
    plan_route,
    read_connection,
)
from app.routing.settings import routing_settings

router = APIRouter(prefix="/networks", tags=["routing"])

ConnDep = Annotated[Connection, Depends(read_connection)]


def routing_error(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RoutingError)
    return JSONResponse({"code": exc.code, "message": exc.message}, status_code=exc.status)


def include_routing(app: FastAPI) -> None:
    """Mount the routing endpoints and their error responses on the app."""
    app.include_router(router)
    app.add_exception_handler(RoutingError, routing_error)


def _json(body: dict[str, Any]) -> Response:
    """Serialise with orjson directly: routes are big nested dicts, and FastAPI's generic
    encoder would take longer than the route search itself."""
    return Response(orjson.dumps(body, option=orjson.OPT_SERIALIZE_NUMPY),
                    media_type="application/json")


def _avoid(raw: str | list[str] | None) -> frozenset[str]:
    if raw is None:
        return frozenset()
    parts = raw.split(",") if isinstance(raw, str) else raw
    return frozenset(p.strip() for p in parts if p.strip())


def _cost(raw: str) -> Cost:
    try:
        return Cost(raw)
    except ValueError:
        raise InvalidQueryError("cost must be 'time' or 'distance'") from None


@router.get("/{name}/route")
def route_get(
    name: str, conn: ConnDep,
    points: Annotated[str, Query(description="lon,lat;lon,lat[;...] visited in order")],
    optimize: bool = False,
    cost: Annotated[str, Query(description="time | distance")] = "time",
    avoid: Annotated[str | None, Query(description="road classes, comma-separated")] = None,
    geometries: Annotated[str, Query(description="geojson | polyline (precision 5)")] = "geojson",
    format: Annotated[str, Query(description="osrm | waypoints")] = "osrm",
    spacing: Annotated[float, Query(description="metres between waypoints")] = 1.0,
    radius: Annotated[float | None, Query(description="snap radius, metres")] = None,
) -> Response:
    """Route through the points (OSRM route-service response)."""
    opts = RouteOptions(_cost(cost), _avoid(avoid), optimize, geometries, format, spacing, radius)
    return _json(plan_route(conn, name, parse_points(points), opts))


@router.get("/{name}/route/v1/{profile}/{coordinates}")
def route_osrm_url(
    name: str, profile: str, coordinates: str, conn: ConnDep,
    geometries: Annotated[str, Query(description="polyline (OSRM default) | geojson")] = "polyline",
) -> Response:
    """OSRM's own URL shape: an OSRM client given ``/networks/{name}`` as its server works
    unchanged. ``profile`` is accepted and ignored (one vehicle profile per network); OSRM
    options other than ``geometries`` are ignored, steps and annotations are always sent."""
    opts = RouteOptions(geometries=geometries)
    return _json(plan_route(conn, name, parse_points(coordinates), opts))


class RouteBody(BaseModel):
    """POST body for long point lists; same options as the query string."""

    points: list[Any] = Field(description="[[lon, lat], ...]")
    optimize: bool = False
    cost: str = "time"
    avoid: list[str] = Field(default_factory=list)
    geometries: str = "geojson"
    format: str = "osrm"
    spacing: float = 1.0
    radius: float | None = None


def _body_point(i: int, raw: Any) -> tuple[float, float]:
    """A [lon, lat] pair from the JSON body; malformed input is a 400, like the query string."""
    try:
        lon, lat = (float(v) for v in raw)
    except (TypeError, ValueError):
        raise InvalidQueryError(f"point {i} {raw!r} is not [lon, lat]") from None
    return check_point(i, lon, lat)


@router.post("/{name}/route")
def route_post(name: str, body: RouteBody, conn: ConnDep) -> Response:
    points = [_body_point(i, p) for i, p in enumerate(body.points)]
    opts = RouteOptions(_cost(body.cost), _avoid(body.avoid), body.optimize, body.geometries,
                        body.format, body.spacing, body.radius)
    return _json(plan_route(conn, name, points, opts))


@router.get("/{name}/isochrone")
def isochrone(
    name: str, conn: ConnDep,
    point: Annotated[str, Query(description="lon,lat")],
    seconds: float | None = None, meters: float | None = None,
    avoid: Annotated[str | None, Query(description="road classes, comma-separated")] = None,
    radius: float | None = None,
) -> Response:
    """Segments (partly) reachable from the point within ``seconds`` or ``meters``."""
    if (seconds is None) == (meters is None):
        raise InvalidQueryError("give exactly one of seconds= or meters=")
    budget = seconds if seconds is not None else meters
    limits = routing_settings()
    most = limits.max_isochrone_seconds if seconds is not None else limits.max_isochrone_meters
    if not 0 < budget <= most:
        raise InvalidQueryError(f"the budget must be in (0, {most:g}]")
    pts = parse_points(point)
    if len(pts) != 1:
        raise InvalidQueryError("isochrone takes exactly one point")
    avoid_set = _avoid(avoid)
    snapped, graph = current_graph(conn, name, pts, avoid_set, radius)
    cost = Cost.TIME if seconds is not None else Cost.DISTANCE
    return _json(isochrone_geojson(graph, graph.costs(cost, avoid_set), snapped.snaps[0],
                                   avoid_set, budget, "s" if seconds is not None else "m"))
