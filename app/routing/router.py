"""HTTP endpoints of OSRM's services and ours: ``route``, ``nearest``, ``table``, ``match`` and
``trip`` on OSRM's own URL shape ``/networks/{name}/{service}/v1/{profile}/{coordinates}`` and
on ours (``/networks/{name}/{service}?points=...``, and POST with a JSON body for long point
lists), plus ``/networks/{name}/isochrone``.

Responses follow OSRM's services. Errors are ``{"code", "message"}`` with OSRM's codes; on our
URLs they take the service's statuses (400 malformed, 422 a value that breaks a rule or a
point that cannot snap or connect), on the OSRM-shaped URLs every OSRM code is a 400 as OSRM
answers it (:data:`OSRM_STATUS_CODES`). Reads need ``UGVMAP_NETWORK_READ_ROLE`` when it is set, like
every other read of network data. Each request reads the network's version on the event
loop, then plans on the loop when that is quick, else in one thread-pool hop (:func:`_answer`);
table, match, trip and isochrone work waits for a slot of its kind's lane (:mod:`app.lanes`),
or is refused at once with 503 ``ServiceBusy`` when that lane's queue is full.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any

import orjson
from fastapi import APIRouter, Depends, FastAPI, Path, Request
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from app import errors
from app.api.dependencies import read_access
from app.api.errors import (
    STATUS_CODES,
    Answer,
    PayloadTooLargeError,
    Table,
    fault_response,
    responses,
)
from app.api.query import only_query
from app.lanes import Kind, held_on_arrival, lane
from app.routing import params
from app.routing.bodies import ServiceBody, body_model
from app.routing.graph import RoadGraph
from app.routing.options import (
    ISOCHRONE_OPTIONS,
    SERVICES,
    Service,
    UrlFamily,
    option_names,
    parse,
    parse_isochrone,
    parse_points,
    service_docs,
)
from app.routing.planner import current_graph, plan_isochrone, plan_route, quick_route
from app.routing.profiles import ALIASES, DEFAULT, PROFILES
from app.routing.reads import ReadAhead, version_reader
from app.routing.service_options import parse_match, parse_nearest, parse_table, parse_trip
from app.routing.services import plan_match, plan_nearest, plan_table, plan_trip
from app.routing.settings import routing_settings

# What any routing operation may answer besides 200: OSRM's 400 codes, the read role, an
# unknown network, the body limit, value rules, unreachable points and the output caps.
router = APIRouter(prefix="/networks", tags=["routing"],
                   dependencies=[Depends(read_access)],
                   responses=responses(
                       errors.InvalidParameterValueError, errors.InvalidQueryError,
                       errors.InvalidOptionsError, errors.TooBigError, errors.InvalidUrlError,
                       errors.InvalidVersionError, errors.NotImplementedOptionError,
                       errors.UnauthorizedError, errors.ForbiddenError, errors.NotFoundError,
                       PayloadTooLargeError, errors.InvalidValueError,
                       errors.NoSegmentError, errors.NoRouteError, errors.NoTripsError,
                       errors.NoMatchError, errors.InvalidServiceError,
                       errors.ResponseTooLargeError, errors.DatabaseUnavailableError,
                       errors.ServiceBusyError))

PROFILE = re.compile(r"[A-Za-z0-9_.-]{1,64}", re.ASCII)
HEAVY_SERVICES: dict[Service, Kind] = {"table": "table", "match": "match", "trip": "trip"}
"""The services whose work queues in a lane of its own kind (:mod:`app.lanes`)."""
NOT_SERVED = ("tile",)  # OSRM's vector tiles of its graph: /networks/{name}/tiles/... has ours
ISOCHRONE_DOCS = {
    **{n: service_docs("route")[n] for n in ("profile", "avoid", "exclude", "radius")},
    "point": "lon,lat", "seconds": "time budget, s", "meters": "distance budget, m"}
# OSRM's URL family: OSRM's own server answers every error with 400, so on the OSRM-shaped URLs
# the faults that are a 422 on ours take that status (and OSRM's names for two codes), so OSRM
# clients branch as they do against OSRM. Every other fault answers as on our URLs.
OSRM_STATUS_CODES: Table = {
    **STATUS_CODES,
    errors.InvalidValueError: Answer(400, "InvalidValue"),
    errors.NoSegmentError: Answer(400, "NoSegment"),
    errors.NoRouteError: Answer(400, "NoRoute"),
    errors.NoTripsError: Answer(400, "NoTrips"),
    errors.NoMatchError: Answer(400, "NoMatch"),
    errors.ResponseTooLargeError: Answer(400, "TooBig"),  # OSRM calls every size limit TooBig
    errors.InvalidParameterValueError: Answer(400, "InvalidUrl"),
}


def include_routing(app: FastAPI) -> None:
    """Mount the routing endpoints on the app."""
    app.include_router(router)
    app.include_router(profiles_router)


# The vehicle profiles are not network data: listed publicly, for clients such as the web
# map's route tool, which names the one it routes with and offers the others.
profiles_router = APIRouter(tags=["routing"])


@profiles_router.get("/routing/profiles", dependencies=[only_query()])
async def vehicle_profiles() -> Response:
    """The vehicle profiles a route may name (``profile=`` or OSRM's profile path segment):
    each one's name, other names, what it is and the road classes it never drives."""
    return _json({"default": DEFAULT.name, "profiles": [
        {"name": p.name, "aliases": [a for a, n in ALIASES.items() if n == p.name],
         "title": p.title, "never": sorted(p.forbidden)} for p in PROFILES.values()]})


def _query_doc(names: list[str], docs: dict[str, str]) -> dict[str, Any]:
    """OpenAPI parameters for options read from the raw query string (one table, no copy)."""
    return {"parameters": [{"name": n, "in": "query", "required": n in ("points", "point"),
                            "description": docs[n], "schema": {"type": "string"}}
                           for n in names]}


def _service_doc(service: Service, family: UrlFamily) -> dict[str, Any]:
    return _query_doc(list(option_names(service, family)), service_docs(service))


def _json(body: dict[str, Any]) -> Response:
    """Serialise with orjson directly: routes are big nested dicts, and FastAPI's generic
    encoder would take longer than the route search itself."""
    return Response(orjson.dumps(body, option=orjson.OPT_SERIALIZE_NUMPY),
                    media_type="application/json")


@dataclass(frozen=True)
class Call:
    """A planner call answering a request: the function, its arguments after the reads and
    the network name, and whether it is quick on a given graph."""

    plan: Callable[..., dict[str, Any]]
    args: tuple
    quick: Callable[[RoadGraph], bool] = lambda graph: False
    heavy: Kind | None = None  # the lane its work queues in (app.lanes); None: no lane


@dataclass(frozen=True)
class Early:
    """A plan made before the version read came back, on the graph of ``version``: its
    response, or the domain error it raised."""

    network_id: int
    version: int
    response: Response | None
    error: errors.UgvmapError | None

    def stands(self, ahead: ReadAhead) -> bool:
        """Whether the plan holds every edit the version read says is committed."""
        return self.network_id == ahead.network_id and self.version >= ahead.version


def _plan_early(name: str, network_id: int | None, call: Call) -> Early | None:
    """Plan on the graph this process holds of ``network_id`` (the name's id when last read),
    when the call is quick on it."""
    graph = current_graph(network_id, 0) if network_id is not None else None
    if graph is None or not call.quick(graph):
        return None
    ahead = ReadAhead(name, graph.network_id, graph.version)
    try:
        return Early(graph.network_id, graph.version,
                     _json(call.plan(ahead, name, *call.args)), None)
    except errors.UgvmapError as exc:
        return Early(graph.network_id, graph.version, None, exc)


async def _answer(name: str, call: Call) -> Response:
    """Read the network's version on the event loop and run the planner: on the loop when
    it is quick there (a route of a few points, everything it needs built: see
    :func:`app.routing.planner.quick_route`), since a worker-thread hop cost more than such a
    planner (two thread wake-ups per request: ~0.2 ms of wall time and of CPU, measured on
    Andorra); else in one worker-thread hop (a search, a load or a catch-up that may take
    long must not hold the loop).

    A quick plan runs while the database answers the read (its round trip was ~0.15 ms of a
    1.3 ms Andorra route), on the graph this process holds; it stands when that graph holds
    the version read, nearly always since the listener applies an edit within milliseconds.
    Else the request plans again, on a graph at that version, as it would have anyway."""
    reader = version_reader()
    read = reader.begin(name)
    try:
        early = _plan_early(name, reader.known_id(name), call)
    except BaseException:
        read.abandon()
        raise
    ahead = await read.result()
    if early is not None and early.stands(ahead):
        if early.error is not None:
            raise early.error
        assert early.response is not None
        return early.response
    graph = current_graph(ahead.network_id, ahead.version)
    if graph is not None and call.quick(graph):
        return _json(call.plan(ahead, name, *call.args))
    if call.heavy is None:
        return await run_in_threadpool(lambda: _json(call.plan(ahead, name, *call.args)))
    async with lane(call.heavy).slot():
        return await run_in_threadpool(lambda: _json(call.plan(ahead, name, *call.args)))


def _raw(request: Request) -> dict[str, str]:
    """The query string as one value per option; an option given twice is refused."""
    raw: dict[str, str] = {}
    for key, value in request.query_params.multi_items():
        if key in raw:
            raise errors.InvalidQueryError(f"option {key[:40]!r} is given more than once")
        raw[key] = value
    return raw


def _most_points(service: Service) -> int:
    """How many points a service's coordinates may hold (bounds the text before parsing)."""
    limits = routing_settings()
    return {"route": limits.max_points, "nearest": 1, "table": limits.max_table_size ** 2,
            "match": limits.max_match_points, "trip": limits.max_trip_points}[service]


def _request(service: Service, raw: dict[str, str], family: UrlFamily,
             points: list[tuple[float, float]], vehicle: str | None = None) -> Call:
    """The planner call answering a request (``vehicle``: OSRM's profile path segment)."""
    opts = parse(raw, family, len(points), service, vehicle)
    n = len(points)
    if service == "nearest":
        return Call(plan_nearest, (points[0], opts, parse_nearest(raw, n)))
    if service == "table":
        return Call(plan_table, (points, opts, parse_table(raw, n)), heavy="table")
    if service == "match":
        return Call(plan_match, (points, opts, parse_match(raw, n)), heavy="match")
    if service == "trip":
        return Call(plan_trip, (points, opts, parse_trip(raw, n)), heavy="trip")
    return Call(plan_route, (points, opts), lambda graph: quick_route(graph, n, opts))


async def answer_get(service: Service, name: str, request: Request) -> Response:
    """A GET of our URL family (``/networks/{name}/{service}?points=...``)."""
    params.network_name(name)
    raw = _raw(request)
    return await _own(service, name, raw, _query_points(service, raw))


async def _own(service: Service, name: str, raw: dict[str, str],
               points: list[tuple[float, float]]) -> Response:
    return await _answer(name, _request(service, raw, "ugvmap", points))


def _query_points(service: Service, raw: dict[str, str]) -> list[tuple[float, float]]:
    key = "point" if service == "nearest" else "points"
    if key not in raw:
        shape = "lon,lat" if service == "nearest" else "lon,lat;lon,lat[;...]"
        raise errors.InvalidQueryError(f"{key}= ({shape}) is required")
    return parse_points(raw[key], _most_points(service))


@router.get("/{name}/route", openapi_extra=_service_doc("route", "ugvmap"))
async def route_get(name: str, request: Request) -> Response:
    """Route through the points (OSRM route-service response; options in the README)."""
    return await answer_get("route", name, request)


@router.get("/{name}/nearest", openapi_extra=_service_doc("nearest", "ugvmap"))
async def nearest_get(name: str, request: Request) -> Response:
    """The nearest road segments to a point (OSRM nearest-service response)."""
    return await answer_get("nearest", name, request)


@router.get("/{name}/table", openapi_extra=_service_doc("table", "ugvmap"),
            dependencies=[Depends(held_on_arrival("table"))])
async def table_get(name: str, request: Request) -> Response:
    """Durations and distances between the points (OSRM table-service response)."""
    return await answer_get("table", name, request)


@router.get("/{name}/match", openapi_extra=_service_doc("match", "ugvmap"),
            dependencies=[Depends(held_on_arrival("match"))])
async def match_get(name: str, request: Request) -> Response:
    """The roads a GNSS trace drove (OSRM match-service response)."""
    return await answer_get("match", name, request)


@router.get("/{name}/trip", openapi_extra=_service_doc("trip", "ugvmap"),
            dependencies=[Depends(held_on_arrival("trip"))])
async def trip_get(name: str, request: Request) -> Response:
    """The best order to visit the points, and the route (OSRM trip-service response)."""
    return await answer_get("trip", name, request)


async def _posted(service: Service, name: str, body: ServiceBody) -> Response:
    params.network_name(name)
    points = body.point_list()
    if len(points) > _most_points(service):
        raise errors.TooBigError(f"{len(points)} points; {service} takes at most "
                                 f"{_most_points(service)}")
    return await _own(service, name, body.raw(), points)


def _post_endpoint(service: Service) -> Callable[..., Any]:
    async def endpoint(name: str, body: ServiceBody) -> Response:
        return await _posted(service, name, body)

    endpoint.__annotations__["body"] = body_model(service)  # the service's own fields
    endpoint.__name__ = f"{service}_post"
    endpoint.__doc__ = (f"The {service} service for a long list of points sent as a JSON body "
                        "(the GET's options, as JSON values).")
    return endpoint


async def answer_osrm(service: Service, name: str, request: Request, version: str,
                      profile: str, coordinates: str) -> Response:
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
        points = parse_points(coordinates.removesuffix(".json"), _most_points(service))
        return await _answer(name, _request(service, _raw(request), "osrm", points, profile))
    except errors.UgvmapError as exc:
        return fault_response(exc, OSRM_STATUS_CODES)


def _osrm_endpoint(service: Service) -> Callable[..., Any]:
    async def endpoint(
        name: str, request: Request,
        version: Annotated[str, Path(description="OSRM protocol version: v1")],
        profile: Annotated[str, Path(description="the vehicle: car (or driving), sidewalk (or "
                                                 "robot)")],
        coordinates: Annotated[str, Path(description="lon,lat;lon,lat[;...][.json] or "
                                                      "polyline(...) / polyline6(...)")],
    ) -> Response:
        return await answer_osrm(service, name, request, version, profile, coordinates)

    endpoint.__name__ = f"{service}_osrm_url"
    endpoint.__doc__ = (f"OSRM's {service} service on OSRM's own URL shape, with OSRM's "
                        "defaults and OSRM's 400 for every error code.")
    return endpoint


for _service in SERVICES:
    router.add_api_route(f"/{{name}}/{_service}/{{version}}/{{profile}}/{{coordinates}}",
                         _osrm_endpoint(_service), methods=["GET"],
                         openapi_extra=_service_doc(_service, "osrm"),
                         dependencies=[Depends(held_on_arrival(HEAVY_SERVICES[_service]))]
                         if _service in HEAVY_SERVICES else None)
# The POST bodies after the GETs: FastAPI tries a router's routes in order, and every GET of
# OSRM's URL shape (most requests) would otherwise be matched against these first.
# A heavy service takes its place in its lane before its points are parsed (5,000 points took
# the event loop ~50 ms each, only to be told 503; issue 33).
router.add_api_route("/{name}/route", _post_endpoint("route"), methods=["POST"])
for _heavy, _kind in HEAVY_SERVICES.items():
    router.add_api_route(f"/{{name}}/{_heavy}", _post_endpoint(_heavy), methods=["POST"],
                         dependencies=[Depends(held_on_arrival(_kind))])


@router.get("/{name}/{service}/{version}/{profile}", include_in_schema=False)
async def osrm_without_coordinates(name: str, service: str, version: str,
                                   profile: str) -> Response:
    """OSRM's URL with the coordinates missing: OSRM's ``InvalidUrl`` (for OSRM's service
    names; any other path here is an unknown path)."""
    if service not in (*SERVICES, *NOT_SERVED):
        raise errors.NotFoundError(f"no such path: /networks/{name[:64]}/{service[:40]}/...")
    raise errors.InvalidUrlError(
        f"the URL has no coordinates: /{service[:40]}/v1/{{profile}}/{{lon,lat;...}}")


@router.get("/{name}/{service}/v1/{profile}/{coordinates}", include_in_schema=False)
async def osrm_other_service(name: str, service: str, profile: str,
                             coordinates: str) -> Response:
    """OSRM's ``tile`` service: refused with OSRM's ``InvalidService``; any other path here is
    an unknown path."""
    if service not in NOT_SERVED:
        raise errors.NotFoundError(f"no such path: /networks/{name[:64]}/{service[:40]}/v1/...")
    raise errors.InvalidServiceError(f"service {service!r} is not served here: "
                                     f"{', '.join(SERVICES)} are")


@router.get("/{name}/isochrone", openapi_extra=_query_doc(list(ISOCHRONE_OPTIONS),
                                                          ISOCHRONE_DOCS),
            dependencies=[Depends(held_on_arrival("isochrone"))])
async def isochrone(name: str, request: Request) -> Response:
    """Segments (partly) reachable from the point within ``seconds`` or ``meters``."""
    params.network_name(name)
    return await _answer(name, Call(plan_isochrone, (parse_isochrone(_raw(request)),),
                                    heavy="isochrone"))
