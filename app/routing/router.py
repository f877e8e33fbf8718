"""HTTP endpoints: ``/networks/{name}/route`` (GET and POST) and ``/networks/{name}/isochrone``.

Responses follow the OSRM route service; errors are ``{"code", "message"}`` with OSRM codes
(``InvalidQuery``, ``TooBig``, ``NoSegment``, ``NoRoute``) and ``NotFound`` for an unknown
network. Each request does its database read and search in one thread-pool hop (:func:`_answer`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

import orjson
from fastapi import APIRouter, FastAPI, Query
from fastapi.responses import Response
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool

from app.errors import InvalidQueryError
from app.routing.costs import Cost
from app.routing.planner import (
    RouteOptions,
    check_point,
    parse_points,
    plan_isochrone,
    plan_route,
    read_connection,
)

router = APIRouter(prefix="/networks", tags=["routing"])


def include_routing(app: FastAPI) -> None:
    """Mount the routing endpoints on the app."""
    app.include_router(router)


def _json(body: dict[str, Any]) -> Response:
    """Serialise with orjson directly: routes are big nested dicts, and FastAPI's generic
    encoder would take longer than the route search itself."""
    return Response(orjson.dumps(body, option=orjson.OPT_SERIALIZE_NUMPY),
                    media_type="application/json")


async def _answer(plan: Callable[..., dict[str, Any]], *args: Any) -> Response:
    """Run a planner call, with its own connection, in one worker-thread hop: the snap blocks
    on the database and the search is CPU-bound, so neither may run on the event loop (and a
    connection dependency would cost two more hops per request)."""
    def work() -> Response:
        with read_connection() as conn:
            return _json(plan(conn, *args))

    return await run_in_threadpool(work)


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
async def route_get(
    name: str,
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
    return await _answer(plan_route, name, parse_points(points), opts)


@router.get("/{name}/route/v1/{profile}/{coordinates}")
async def route_osrm_url(
    name: str, profile: str, coordinates: str,
    geometries: Annotated[str, Query(description="polyline (OSRM default) | geojson")] = "polyline",
) -> Response:
    """OSRM's own URL shape: an OSRM client given ``/networks/{name}`` as its server works
    unchanged. ``profile`` is accepted and ignored (one vehicle profile per network); OSRM
    options other than ``geometries`` are ignored, steps and annotations are always sent."""
    opts = RouteOptions(geometries=geometries)
    return await _answer(plan_route, name, parse_points(coordinates), opts)


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
async def route_post(name: str, body: RouteBody) -> Response:
    """Route through a long list of points sent as a JSON body (same options as GET)."""
    points = [_body_point(i, p) for i, p in enumerate(body.points)]
    opts = RouteOptions(_cost(body.cost), _avoid(body.avoid), body.optimize, body.geometries,
                        body.format, body.spacing, body.radius)
    return await _answer(plan_route, name, points, opts)


@router.get("/{name}/isochrone")
async def isochrone(
    name: str,
    point: Annotated[str, Query(description="lon,lat")],
    seconds: float | None = None, meters: float | None = None,
    avoid: Annotated[str | None, Query(description="road classes, comma-separated")] = None,
    radius: float | None = None,
) -> Response:
    """Segments (partly) reachable from the point within ``seconds`` or ``meters``."""
    pts = parse_points(point)
    if len(pts) != 1:
        raise InvalidQueryError("isochrone takes exactly one point")
    return await _answer(plan_isochrone, name, pts[0], seconds, meters, _avoid(avoid), radius)
