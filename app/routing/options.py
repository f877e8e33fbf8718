"""Route options: one table of every option, parsed the same way from a query string, a JSON
body or the CLI, with the defaults of the URL that received them.

Two URL families take the same options and differ only in defaults: our ``/route`` answers a
vehicle planner (GeoJSON, full overview, steps), the OSRM-shaped ``/route/v1/...`` answers like
OSRM (polyline, simplified overview, no steps). Unknown options and invalid values are refused
(400 ``InvalidQuery`` when they do not parse, ``InvalidOptions`` when per-point lists do not
match the points, ``InvalidValue`` when out of range), never silently ignored.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Literal

import polyline

from app.db.models import SLUG_RE
from app.errors import (
    InvalidOptionsError,
    InvalidQueryError,
    InvalidValueError,
    NotImplementedOptionError,
    TooBigError,
)
from app.routing import params
from app.routing.costs import Cost
from app.routing.profiles import DEFAULT, OffroadSettings, VehicleProfile, profile_named
from app.routing.settings import routing_settings

GEOMETRIES = ("geojson", "polyline", "polyline6")
OVERVIEWS = ("full", "simplified", "false")
FORMATS = ("osrm", "waypoints")
APPROACHES = ("unrestricted", "curb", "opposite")
ANNOTATIONS = ("nodes", "distance", "duration", "speed", "weight", "datasources")

# exclude= classes (OSRM's option) -> the road_class values they stand for. OSRM's profile
# classes that need data we do not hold (toll, ferry, tunnel, restricted) are unknown here.
EXCLUDE_CLASSES: dict[str, tuple[str, ...]] = {
    "motorway": ("motorway", "motorway_link"),
    "trunk": ("trunk", "trunk_link"),
    "primary": ("primary", "primary_link"),
    "secondary": ("secondary", "secondary_link"),
    "tertiary": ("tertiary", "tertiary_link"),
    "unclassified": ("unclassified", "road"),
    "residential": ("residential", "living_street"),
    "service": ("service",),
    "track": ("track",),
    "path": ("path", "footway", "cycleway", "bridleway", "pedestrian", "steps", "corridor"),
}
ROAD_CLASS = re.compile(r"[A-Za-z0-9_:.-]{1,64}", re.ASCII)
HINT = re.compile(r"[A-Za-z0-9+/=_-]{0,512}", re.ASCII)
MAX_CLASSES = 32
MAX_OPTION_CHARS = 2048  # any one option's value, before it is split
MATCH_SIGMA_M = 5.0  # match's default GPS precision (OSRM's DEFAULT_GPS_PRECISION)
POINT_CHARS = 64  # per point in points= / radiuses= / bearings= ...; hints get HINT's 512

UrlFamily = Literal["ugvmap", "osrm"]
# Options that shape an OSRM answer, which format=waypoints does not give.
OSRM_SHAPE = frozenset({"geometries", "overview", "steps", "annotations", "alternatives",
                        "generate_hints", "skip_waypoints"})


@dataclass(frozen=True)
class PointOptions:
    """What one input point asks of its snap: a radius, a bearing, an approach side."""

    radius_m: float
    bearing: tuple[int, int] | None = None  # (value, range) in degrees
    approach: str = "unrestricted"


@dataclass(frozen=True)
class OffroadRequest:
    """What ``offroad=true`` asks (issue 37): the elevation layer driven on (the DTM), the
    vehicle's off-road settings (its profile's, with ``max_slope=`` / ``max_step=``
    applied), the DSM whose height above the DTM is a step, and the layers that forbid."""

    elevation: str
    settings: OffroadSettings
    surface: str | None = None
    forbid: tuple[str, ...] = ()


@dataclass
class RouteOptions:
    """A route request's options, shared by the query string, the POST body and the CLI."""

    cost: Cost = Cost.TIME
    # road classes never driven: avoid=, exclude= mapped, and the vehicle profile's
    avoid: frozenset[str] = field(default_factory=frozenset)
    vehicle: VehicleProfile = DEFAULT
    optimize: bool = False
    geometries: str = "geojson"
    overview: str = "full"
    steps: bool = True
    annotations: frozenset[str] = frozenset()
    alternatives: int = 0
    continue_straight: bool = False
    generate_hints: bool = True
    skip_waypoints: bool = False
    format: str = "osrm"
    spacing_m: float = 1.0
    radius_m: float | None = None  # default snap radius for points without radiuses=
    points: tuple[PointOptions, ...] = ()  # one per input point, filled by :func:`parse`
    offroad: OffroadRequest | None = None  # offroad=true (our URL and the CLI only)

    def point(self, i: int) -> PointOptions:
        """Point ``i``'s snap options (the request-wide radius when none were given)."""
        if self.points:
            return self.points[i]
        return PointOptions(self.radius_m if self.radius_m is not None
                            else routing_settings().snap_radius_m)

    def check(self, n_points: int) -> None:
        """Refuse requests outside the limits before any search starts."""
        limits = routing_settings()
        if n_points < 2:
            raise InvalidOptionsError("a route needs at least two points")
        if n_points > limits.max_points:
            raise TooBigError(f"{n_points} points; at most {limits.max_points} per route")
        if self.optimize and n_points > limits.max_optimize_points:
            raise TooBigError(f"{n_points} points; optimize=true takes at most "
                              f"{limits.max_optimize_points}")


DEFAULTS: dict[UrlFamily, dict[str, str]] = {
    "ugvmap": {"geometries": "geojson", "overview": "full", "steps": "true"},
    "osrm": {"geometries": "polyline", "overview": "simplified", "steps": "false"},
}
Service = Literal["route", "nearest", "table", "match", "trip"]
SERVICES: tuple[Service, ...] = ("route", "nearest", "table", "match", "trip")
_COMMON = ("cost", "avoid", "exclude", "radius", "radiuses", "bearings", "approaches", "hints",
           "generate_hints", "skip_waypoints", "snapping")
_SHAPE = ("geometries", "overview", "steps", "annotations")
# The options of each service on both URL families (OSRM's, then ours: cost, avoid, radius,
# optimize). Match's ``radiuses`` are GPS precisions, not snap radii, so it has no ``radius``.
SERVICE_OPTIONS: dict[Service, tuple[str, ...]] = {
    "route": (*_COMMON, *_SHAPE, "alternatives", "continue_straight", "waypoints", "optimize"),
    "nearest": (*_COMMON, "number"),
    "table": (*_COMMON, "sources", "destinations", "annotations", "fallback_speed",
              "fallback_coordinate", "scale_factor"),
    "match": (*(n for n in _COMMON if n != "radius"), *_SHAPE, "timestamps", "gaps", "tidy",
              "waypoints"),
    "trip": (*_COMMON, *_SHAPE, "roundtrip", "source", "destination"),
}
# Ours only: the points (the path on OSRM's URLs), and dense waypoints instead of OSRM's answer.
# The vehicle profile is OSRM's path segment on its URLs, ``profile=`` on ours.
OFFROAD_OPTIONS = ("offroad", "elevation", "surface", "forbid", "max_slope", "max_step")
OWN_URL_OPTIONS: dict[Service, tuple[str, ...]] = {
    "route": ("points", "profile", "format", "spacing", *OFFROAD_OPTIONS),
    "nearest": ("point", "profile"), "table": ("points", "profile"), "match": ("points", "profile"),
    "trip": ("points", "profile")}


def option_names(service: Service, family: UrlFamily) -> tuple[str, ...]:
    """Every option a service takes on URL family ``family``."""
    return (*(OWN_URL_OPTIONS[service] if family == "ugvmap" else ()),
            *SERVICE_OPTIONS[service])


DOCS: dict[str, str] = {
    "points": "lon,lat;lon,lat[;...] visited in order (or polyline(...) / polyline6(...))",
    "profile": "the vehicle: car (default; or driving) never drives footways, cycleways, "
               "paths, steps...; sidewalk (or robot) may",
    "cost": "time (default) | distance: what the route minimises",
    "avoid": "road classes never driven, comma-separated (road_class values)",
    "exclude": f"OSRM classes never driven, comma-separated: {', '.join(EXCLUDE_CLASSES)}",
    "optimize": "true: best order of the intermediate points (first and last fixed)",
    "geometries": "geojson | polyline (precision 5) | polyline6",
    "overview": "full | simplified (Douglas-Peucker at the zoom that shows the route) | false",
    "steps": "true | false: turn-by-turn steps",
    "annotations": "true | false | any of nodes,distance,duration,speed,weight,datasources",
    "alternatives": "true | false | N: up to N clearly different alternatives (two points)",
    "continue_straight": "default (= false) | true: no u-turn at intermediate points",
    "radius": "snap radius for every point, metres, or unlimited",
    "radiuses": "per point: metres or unlimited, ';'-separated, empty for the default",
    "bearings": "per point: value,range in degrees (0..360, 0..180), empty for any",
    "approaches": "per point: unrestricted | curb | opposite (driving side from settings)",
    "hints": "per point: hints from an earlier answer (accepted, not needed)",
    "generate_hints": "true | false: waypoint hints in the answer",
    "skip_waypoints": "true | false: leave out the waypoints array",
    "snapping": "default | any (the same here: every component is routable)",
    "waypoints": "not implemented (400 NotImplemented): every point ends a leg",
    "format": "osrm | waypoints (dense points in a local metric frame)",
    "spacing": "metres between dense waypoints (format=waypoints)",
    "offroad": "true | false (default): points farther than the snap radius from every road "
               "get off-road legs over elevation= (docs/terrain.md)",
    "elevation": "offroad=true: the elevation layer (DTM) the vehicle drives on",
    "surface": "offroad=true: the elevation layer (DSM) whose height above elevation= is a step",
    "forbid": "offroad=true: raster layers, comma-separated, whose pixels above 0 are never "
              "driven (water, buildings)",
    "max_slope": "offroad=true: the steepest slope driven, degrees (default: the profile's)",
    "max_step": "offroad=true: the highest step crossed, metres (default: the profile's)",
    "point": "lon,lat",
    "number": "how many nearest segments (1..max_nearest_number)",
    "sources": "all | i;j;...: indices of the points the rows start from",
    "destinations": "all | i;j;...: indices of the points the columns end at",
    "fallback_speed": "m/s > 0: crow-flies estimate for cells with no route",
    "fallback_coordinate": "input | snapped: where the crow-flies estimate is measured from",
    "scale_factor": "> 0: multiplies every duration",
    "timestamps": "per point: UNIX seconds, non-decreasing",
    "gaps": "split | ignore: split the trace where samples are far apart in time",
    "tidy": "true | false: drop points within 15 m / 5 s of the previous one first",
    "roundtrip": "true | false: return to the first point",
    "source": "any | first: where the trip starts",
    "destination": "any | last: where the trip ends",
}
# What an option means where it differs from the route service.
SERVICE_DOCS: dict[Service, dict[str, str]] = {
    "route": {}, "nearest": {"points": DOCS["point"]},
    "table": {"annotations": "duration | distance | duration,distance (default duration)",
              "points": "lon,lat;lon,lat[;...]: the table's points"},
    "match": {"radiuses": "per point: GPS standard deviation, metres (default 5); candidates "
                          "within 3 of them",
              "waypoints": "i;j;...: the points that end legs (first and last included); "
                           "default all",
              "points": "lon,lat;lon,lat[;...]: the trace, in time order"},
    "trip": {"points": "lon,lat;lon,lat[;...]: the points to visit"},
}


def service_docs(service: Service) -> dict[str, str]:
    """What each option of ``service`` means (for the API document)."""
    return {**DOCS, **SERVICE_DOCS[service]}


def check_names(raw: Mapping[str, object], family: UrlFamily, service: Service = "route"
                ) -> None:
    """400 ``InvalidQuery`` for an option this URL does not take (OSRM refuses them too)."""
    names = option_names(service, family)
    unknown = sorted(k for k in raw if k not in names)
    if unknown:
        raise InvalidQueryError(f"unknown option {unknown[0][:40]!r}; this URL takes "
                                f"{', '.join(names)}")


def parse_points(raw: str, most: int | None = None) -> list[tuple[float, float]]:
    """``lon,lat;lon,lat;...`` (or OSRM's ``polyline(...)``/``polyline6(...)``) -> points; the
    text is bounded by what ``most`` points (``max_points`` by default) can need."""
    most = routing_settings().max_points if most is None else most
    if len(raw) > POINT_CHARS * (most + 1):  # more text than the points allowed can take
        raise TooBigError(f"points is {len(raw):,} characters long: more than {most} points "
                          f"can be; at most {most} points")
    params.bounded("points", raw, POINT_CHARS * (most + 1))
    for precision, prefix in ((6, "polyline6("), (5, "polyline(")):
        if raw.startswith(prefix) and raw.endswith(")"):
            try:
                pairs = polyline.decode(raw[len(prefix):-1], precision)
            except (ValueError, IndexError, TypeError):
                raise InvalidQueryError("points: the polyline does not decode") from None
            return [params.lonlat(i, lon, lat) for i, (lat, lon) in enumerate(pairs)]
    points = []
    for i, part in enumerate(raw.strip().strip(";").split(";")):
        lon_lat = part.split(",")
        if len(lon_lat) != 2:
            raise InvalidQueryError(f"{params.point(i)} {part[:POINT_CHARS]!r} is not 'lon,lat'")
        lon, lat = (params.finite(params.point(i), v) for v in lon_lat)
        points.append(params.lonlat(i, lon, lat))
    return points


def _classes(field_name: str, raw: str) -> list[str]:
    parts = [p.strip() for p in params.bounded(field_name, raw, MAX_OPTION_CHARS).split(",")]
    parts = [p for p in parts if p]
    if len(parts) > MAX_CLASSES:
        raise InvalidQueryError(f"{field_name} lists {len(parts)} classes; at most {MAX_CLASSES}")
    for p in parts:
        if not ROAD_CLASS.fullmatch(p):
            raise InvalidQueryError(f"{field_name}: {p[:40]!r} is not a road class name")
    return parts


def _exclude(raw: str) -> set[str]:
    out: set[str] = set()
    for name in _classes("exclude", raw):
        if name not in EXCLUDE_CLASSES:
            message = (f"exclude class {name!r} is unknown; known: "
                       f"{', '.join(EXCLUDE_CLASSES)}")
            raise InvalidValueError(message, errors={"exclude": message})
        out.update(EXCLUDE_CLASSES[name])
    return out


def _annotations(raw: str) -> frozenset[str]:
    if raw in ("true", "false"):
        return frozenset(ANNOTATIONS) if raw == "true" else frozenset()
    names = params.bounded("annotations", raw, 200).split(",")
    for name in names:
        params.choice("annotations", name, ANNOTATIONS)
    return frozenset(names)


def _alternatives(raw: str) -> int:
    if raw in ("true", "false"):
        return int(raw == "true")
    most = routing_settings().max_alternatives
    n = params.integer_in("alternatives", raw, 0, 10**6)
    if n > most:
        raise TooBigError(f"alternatives={n}; at most {most}")
    return n


def per_point(name: str, raw: str | None, n: int, max_chars: int = POINT_CHARS
               ) -> list[str | None]:
    """OSRM's ``a;b;;d`` lists: exactly one element per point, empty for the default."""
    if raw is None:
        return [None] * n
    parts = params.bounded(name, raw, (max_chars + 1) * n).split(";")
    if len(parts) != n:
        raise InvalidOptionsError(f"{name} has {len(parts)} elements for {n} points; give one "
                                  "per point (empty for the default)")
    return [p or None for p in parts]


def _radius(name: str, raw: str) -> float:
    most = routing_settings().max_snap_radius_m
    if raw == "unlimited":
        return most
    return params.number_in(name, raw, 0.0, most)


def _bearing(i: int, raw: str) -> tuple[int, int]:
    parts = raw.split(",")
    if len(parts) != 2:
        raise InvalidQueryError(f"bearings: {raw!r} of {params.point(i)} is not 'value,range'")
    try:
        return (params.integer_in(f"bearing value of {params.point(i)}", parts[0], 0, 360),
                params.integer_in(f"bearing range of {params.point(i)}", parts[1], 0, 180))
    except InvalidValueError as exc:  # OSRM: parsed, but not a valid bearing
        raise InvalidOptionsError(exc.message) from None


def _points(raw: Mapping[str, str], n: int, default_radius: float) -> tuple[PointOptions, ...]:
    radiuses = per_point("radiuses", raw.get("radiuses"), n)
    bearings = per_point("bearings", raw.get("bearings"), n)
    approaches = per_point("approaches", raw.get("approaches"), n)
    for i, hint in enumerate(per_point("hints", raw.get("hints"), n, max_chars=512)):
        # Hints are accepted (OSRM clients send back the ones we gave) but not used: a snap
        # is one indexed query, cheaper than validating a hint against the current version.
        if hint is not None and not HINT.fullmatch(hint):
            raise InvalidQueryError(f"hints: the hint of {params.point(i)} is not base64")
    return tuple(PointOptions(
        _radius(f"radius of {params.point(i)}", r) if r is not None else default_radius,
        _bearing(i, b) if b is not None else None,
        params.choice(f"approach of {params.point(i)}", a, APPROACHES) if a is not None
        else "unrestricted",
    ) for i, (r, b, a) in enumerate(zip(radiuses, bearings, approaches, strict=True)))


PER_POINT = ("points", "hints", "radiuses", "bearings", "approaches", "timestamps", "sources",
             "destinations", "waypoints")


def parse(raw: Mapping[str, str], family: UrlFamily, n_points: int,
          service: Service = "route", vehicle: str | None = None) -> RouteOptions:
    """Options from raw strings (query string, or a JSON body rendered as strings) for a request
    of ``n_points`` points to ``service`` on URL family ``family``: the ones every service
    shares (snapping, costs, the vehicle: ``vehicle``, OSRM's path segment, or ``profile=``)
    and those that shape routes (route, match, trip). The services' own options are read by
    :mod:`app.routing.service_options`."""
    check_names(raw, family, service)
    for name, value in raw.items():
        if name not in PER_POINT:
            params.bounded(name, value, MAX_OPTION_CHARS)
    if raw.get("waypoints") is not None and service == "route":
        raise NotImplementedOptionError("waypoints= (via points without legs) is not "
                                        "implemented; every point ends a leg")
    if raw.get("snapping") is not None:  # we never restrict snaps to the largest component
        params.choice("snapping", raw["snapping"], ("default", "any"))
    get = {**DEFAULTS[family], **raw}.get
    if service == "table":  # its own annotations (service_options); nothing shapes a route
        get = {**DEFAULTS[family], **{k: v for k, v in raw.items()
                                       if k != "annotations"}}.get
    limits = routing_settings()
    radius = (_radius("radius", get("radius") or "")
              if get("radius") is not None else None)
    driver = profile_named(vehicle if vehicle is not None else get("profile"))
    avoid = set(_classes("avoid", get("avoid") or ""))
    avoid |= _exclude(get("exclude") or "") | driver.forbidden
    continue_straight = params.choice("continue_straight", get("continue_straight", "default"),
                                      ("default", "true", "false"))
    opts = RouteOptions(
        cost=Cost(params.choice("cost", get("cost", "time"), tuple(c.value for c in Cost))),
        avoid=frozenset(avoid),
        vehicle=driver,
        optimize=params.boolean("optimize", get("optimize", "false")),
        geometries=params.choice("geometries", get("geometries", ""), GEOMETRIES),
        overview=params.choice("overview", get("overview", ""), OVERVIEWS),
        steps=params.boolean("steps", get("steps", "")),
        annotations=_annotations(get("annotations", "false")),
        alternatives=_alternatives(get("alternatives", "false")),
        continue_straight=continue_straight == "true",
        generate_hints=params.boolean("generate_hints", get("generate_hints", "true")),
        skip_waypoints=params.boolean("skip_waypoints", get("skip_waypoints", "false")),
        format=params.choice("format", get("format", "osrm"), FORMATS),
        spacing_m=params.number_in("spacing", get("spacing", "1"), limits.min_spacing_m,
                                   limits.max_spacing_m),
        radius_m=radius,
    )
    # nearest looks as far as OSRM's does (no radius), unless told; match reads GPS sigmas
    default_radius = (MATCH_SIGMA_M if service == "match" else radius if radius is not None
                      else limits.max_snap_radius_m if service == "nearest"
                      else limits.snap_radius_m)
    opts.points = _points(raw, n_points, default_radius)
    opts.offroad = _offroad(raw, driver)
    given = set(raw) & (OSRM_SHAPE if opts.format == "waypoints" else {"spacing"})
    if given:
        raise InvalidOptionsError(f"{sorted(given)[0]} does not apply to format={opts.format}")
    if service == "route":
        opts.check(n_points)
    return opts


def _offroad(raw: Mapping[str, str], driver: VehicleProfile) -> OffroadRequest | None:
    """``offroad=true`` and the options that go with it (given without it: refused)."""
    if not params.boolean("offroad", raw.get("offroad", "false")):
        given = sorted(set(raw) & set(OFFROAD_OPTIONS[1:]))
        if given:
            raise InvalidOptionsError(f"{given[0]} applies to offroad=true only")
        return None
    if not raw.get("elevation"):
        raise InvalidOptionsError("offroad=true needs elevation=SLUG: the elevation layer "
                                  "(DTM) the vehicle drives on")
    settings = driver.offroad
    if "max_slope" in raw:
        settings = replace(settings, max_slope_deg=params.number_in(
            "max_slope", raw["max_slope"], 0.0, 89.0, open_low=True))
    if "max_step" in raw:
        settings = replace(settings, max_step_m=params.number_in(
            "max_step", raw["max_step"], 0.0, 100.0))
    forbid = tuple(p for p in raw.get("forbid", "").split(",") if p)
    surface = raw.get("surface") or None
    for name, slug in [("elevation", raw["elevation"]), ("surface", surface),
                       *(("forbid", f) for f in forbid)]:
        if slug is not None and not re.fullmatch(SLUG_RE, slug):
            raise InvalidQueryError(f"{name}: {slug[:40]!r} is not a layer slug")
    return OffroadRequest(raw["elevation"], settings, surface, forbid)


ISOCHRONE_OPTIONS = ("point", "profile", "seconds", "meters", "avoid", "exclude", "radius")


@dataclass(frozen=True)
class IsochroneOptions:
    """An isochrone request: one point, one budget (seconds or metres), avoided classes."""

    point: tuple[float, float]
    budget: float
    cost: Cost
    avoid: frozenset[str]
    snap: PointOptions

    @property
    def unit(self) -> str:
        """``s`` or ``m``, as the answer's properties say."""
        return "s" if self.cost is Cost.TIME else "m"


def parse_isochrone(raw: Mapping[str, str]) -> IsochroneOptions:
    """Isochrone options from raw strings; every number finite and bounded by the settings."""
    unknown = sorted(k for k in raw if k not in ISOCHRONE_OPTIONS)
    if unknown:
        raise InvalidQueryError(f"unknown option {unknown[0][:40]!r}; the isochrone takes "
                                f"{', '.join(ISOCHRONE_OPTIONS)}")
    if "point" not in raw:
        raise InvalidQueryError("point= (lon,lat) is required")
    points = parse_points(raw["point"])
    if len(points) != 1:
        raise InvalidQueryError("isochrone takes exactly one point")
    limits = routing_settings()
    if ("seconds" in raw) == ("meters" in raw):
        raise InvalidQueryError("give exactly one of seconds= or meters=")
    if "seconds" in raw:
        cost, budget = Cost.TIME, params.number_in("seconds", raw["seconds"], 0.0,
                                                   limits.max_isochrone_seconds, open_low=True)
    else:
        cost, budget = Cost.DISTANCE, params.number_in("meters", raw["meters"], 0.0,
                                                       limits.max_isochrone_meters, open_low=True)
    avoid = (set(_classes("avoid", raw.get("avoid", ""))) | _exclude(raw.get("exclude", ""))
             | profile_named(raw.get("profile")).forbidden)
    radius = (_radius("radius", raw["radius"]) if "radius" in raw else limits.snap_radius_m)
    return IsochroneOptions(points[0], budget, cost, frozenset(avoid), PointOptions(radius))
