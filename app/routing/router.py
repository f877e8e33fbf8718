"""HTTP endpoints: ``/networks/{name}/route`` (GET and POST), OSRM's own URL shape
``/networks/{name}/route/v1/{profile}/{coordinates}``, and ``/networks/{name}/isochrone``.

Responses follow the OSRM route service. Errors are ``{"code", "message"}`` with OSRM's codes;
on ``/route`` and ``/isochrone`` they take the service's statuses (400 malformed, 422 a value
that breaks a rule or a point that cannot snap or connect), on the OSRM-shaped URLs every OSRM
code is a 400 as OSRM answers it (:func:`_as_osrm`). Reads need ``UGVMAP_NETWORK_READ_ROLE``
when it is set, like every other read of network data. Each request does its database read
and search in one thread-pool hop (:func:`_answer`).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Annotated, Any

import orjson
from fastapi import APIRouter, Depends, FastAPI, Path, Request
from fastapi.responses import Response
from pydantic import BaseModel, ConfigDict, Field
from starlette.concurrency import run_in_threadpool

from app import errors
from app.network.tokens import read_access
from app.routing import params
from app.routing.options import (
    DOCS,
    ISOCHRONE_OPTIONS,
    OPTIONS,
    Profile,
    parse,
    parse_isochrone,
    parse_points,
)
from app.routing.planner import plan_isochrone, plan_route, read_connection

# What any routing operation may answer besides 200: OSRM's 400 codes, the read role, an
# unknown network, the body limit, value rules, unreachable points and the output caps.
router = APIRouter(prefix="/networks", tags=["routing"], dependencies=[Depends(read_access)],
                   responses=errors.responses(
                       errors.InvalidParameterValueError, errors.InvalidQueryError,
                       errors.InvalidOptionsError, errors.TooBigError, errors.InvalidUrlError,
                       errors.InvalidVersionError, errors.NotImplementedOptionError,
                       errors.UnauthorizedError, errors.ForbiddenError, errors.NotFoundError,
                       errors.PayloadTooLargeError, errors.InvalidValueError,
                       errors.NoSegmentError, errors.NoRouteError,
                       errors.ResponseTooLargeError, errors.DatabaseUnavailableError))

PROFILE = re.compile(r"[A-Za-z0-9_.-]{1,64}", re.ASCII)
OSRM_SERVICES = ("nearest", "table", "match", "trip", "tile")
ISOCHRONE_DOCS = {
    "point": "lon,lat", "seconds": "time budget, s", "meters": "distance budget, m",
    "avoid": DOCS["avoid"], "exclude": DOCS["exclude"], "radius": DOCS["radius"]}
# Our status for a fault -> the class OSRM clients expect on OSRM's URLs (400, same code).
_OSRM_FAULTS: dict[type[errors.ApiError], type[errors.ApiError]] = {
    errors.InvalidValueError: errors.OsrmInvalidValueError,
    errors.NoSegmentError: errors.OsrmNoSegmentError,
    errors.NoRouteError: errors.OsrmNoRouteError,
    errors.ResponseTooLargeError: errors.OsrmTooBigError,
    errors.InvalidParameterValueError: errors.InvalidUrlError,
}


def include_routing(app: FastAPI) -> None:
    """Mount the routing endpoints on the app."""
    app.include_router(router)


def _query_doc(names: list[str], docs: dict[str, str]) -> dict[str, Any]:
    """OpenAPI parameters for options read from the raw query string (one table, no copy)."""
    return {"parameters": [{"name": n, "in": "query", "required": n in ("points", "point"),
                            "description": docs[n], "schema": {"type": "string"}}
                           for n in names]}


def _route_doc(profile: Profile) -> dict[str, Any]:
    return _query_doc([n for n, used in OPTIONS.items() if profile in used], DOCS)


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


def _raw(request: Request) -> dict[str, str]:
    """The query string as one value per option; an option given twice is refused."""
    raw: dict[str, str] = {}
    for key, value in request.query_params.multi_items():
        if key in raw:
            raise errors.InvalidQueryError(f"option {key[:40]!r} is given more than once")
        raw[key] = value
    return raw


@router.get("/{name}/route", openapi_extra=_route_doc("ugvmap"))
async def route_get(name: str, request: Request) -> Response:
    """Route through the points (OSRM route-service response; options in the README)."""
    params.network_name(name)
    raw = _raw(request)
    if "points" not in raw:
        raise errors.InvalidQueryError("points= (lon,lat;lon,lat[;...]) is required")
    points = parse_points(raw["points"])
    return await _answer(plan_route, name, points, parse(raw, "ugvmap", len(points)))


Flag = bool | str | None
Number = float | str | None


class RouteBody(BaseModel):
    """POST body for long point lists: the query string's options, same names and syntax
    (booleans and numbers may also be JSON booleans and numbers, ``avoid`` a list)."""

    model_config = ConfigDict(extra="forbid")

    points: list[Any] = Field(description="[[lon, lat], ...]")
    cost: str | None = None
    avoid: list[str] | str | None = None
    exclude: str | None = None
    optimize: Flag = None
    geometries: str | None = None
    overview: str | None = None
    steps: Flag = None
    annotations: Flag = None
    alternatives: bool | int | str | None = None
    continue_straight: Flag = None
    radius: Number = None
    radiuses: str | None = None
    bearings: str | None = None
    approaches: str | None = None
    hints: str | None = None
    generate_hints: Flag = None
    skip_waypoints: Flag = None
    snapping: str | None = None
    waypoints: str | None = None
    format: str | None = None
    spacing: Number = None

    def raw(self) -> dict[str, str]:
        """The options as the query string would carry them, for the one option parser."""
        out: dict[str, str] = {}
        for key, value in self.model_dump(exclude={"points"}, exclude_none=True).items():
            if isinstance(value, bool):
                out[key] = "true" if value else "false"
            elif isinstance(value, list):
                out[key] = ",".join(value)
            else:
                out[key] = value if isinstance(value, str) else repr(value)
        return out


def _body_point(i: int, raw: Any) -> tuple[float, float]:
    """A [lon, lat] pair from the JSON body; malformed input is a 400, like the query string."""
    if not isinstance(raw, list) or len(raw) != 2 or not all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in raw):
        raise errors.InvalidQueryError(f"point {i} {str(raw)[:60]} is not [lon, lat]")
    lon, lat = (params.finite(f"point {i}", repr(v)) for v in raw)
    return params.lonlat(i, lon, lat)


@router.post("/{name}/route")
async def route_post(name: str, body: RouteBody) -> Response:
    """Route through a long list of points sent as a JSON body (same options as GET)."""
    params.network_name(name)
    points = [_body_point(i, p) for i, p in enumerate(body.points)]
    return await _answer(plan_route, name, points, parse(body.raw(), "ugvmap", len(points)))


def _as_osrm(exc: errors.ApiError) -> errors.ApiError:
    """The same fault as OSRM answers it on its own URLs (400 with OSRM's code)."""
    for ours, osrm in _OSRM_FAULTS.items():
        if type(exc) is ours:
            return osrm(exc.message, errors=exc.errors)
    return exc


@router.get("/{name}/route/{version}/{profile}/{coordinates}", openapi_extra=_route_doc("osrm"))
async def route_osrm_url(
    name: str, request: Request,
    version: Annotated[str, Path(description="OSRM protocol version: v1")],
    profile: Annotated[str, Path(description="any profile name (one vehicle per network)")],
    coordinates: Annotated[str, Path(description="lon,lat;lon,lat[;...][.json] or polyline(...)")],
) -> Response:
    """OSRM's own URL shape: an OSRM client given ``/networks/{name}`` as its server works
    unchanged. OSRM's defaults (polyline, simplified overview, no steps, no annotations) and
    OSRM's 400 for every OSRM error code."""
    try:
        params.network_name(name)
        if version != "v1":
            raise errors.InvalidVersionError(f"version {version[:20]!r} is not supported: v1")
        if not PROFILE.fullmatch(profile):
            raise errors.InvalidUrlError(f"profile {profile[:40]!r} is not a profile name")
        if coordinates.endswith(".flatbuffers"):
            raise errors.NotImplementedOptionError("only the json format is served")
        points = parse_points(coordinates.removesuffix(".json"))
        opts = parse(_raw(request), "osrm", len(points))
        return await _answer(plan_route, name, points, opts)
    except errors.ApiError as exc:
        raise _as_osrm(exc) from exc


@router.get("/{name}/route/{version}/{profile}", include_in_schema=False)
async def route_osrm_without_coordinates(name: str, version: str, profile: str) -> Response:
    """OSRM's URL with the coordinates missing: OSRM's ``InvalidUrl``."""
    raise errors.InvalidUrlError("the URL has no coordinates: /route/v1/{profile}/{lon,lat;...}")


@router.get("/{name}/{service}/v1/{profile}/{coordinates}", include_in_schema=False)
async def osrm_other_service(name: str, service: str, profile: str,
                             coordinates: str) -> Response:
    """OSRM's other services: refused with OSRM's ``InvalidService`` (only ``route`` is
    served); any other path here is an unknown path."""
    if service not in OSRM_SERVICES:
        raise errors.NotFoundError(f"no such path: /networks/{name[:64]}/{service[:40]}/v1/...")
    raise errors.InvalidServiceError(f"service {service!r} is not served here: only route")


@router.get("/{name}/isochrone", openapi_extra=_query_doc(list(ISOCHRONE_OPTIONS),
                                                          ISOCHRONE_DOCS))
async def isochrone(name: str, request: Request) -> Response:
    """Segments (partly) reachable from the point within ``seconds`` or ``meters``."""
    params.network_name(name)
    return await _answer(plan_isochrone, name, parse_isochrone(_raw(request)))
