"""The own options of OSRM's nearest, table, match and trip services, read like OSRM reads them.

The options every service shares (snapping, radii, bearings, costs, avoided classes) and those
that shape routes (match and trip answer with routes) are read by :func:`app.routing.options.parse`;
this module reads the rest and checks each service's limits. Codes follow OSRM: text that does
not parse is ``InvalidQuery``, a well-formed request OSRM's parameter checks refuse (an index
out of range, ``fallback_speed`` not above 0, one point to match) is ``InvalidOptions``, a value
the service cannot use (timestamps going back, waypoints without the first and last point) is
``InvalidValue``, and a request over a limit is ``TooBig``.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass

from app.errors import (
    InvalidOptionsError,
    InvalidQueryError,
    InvalidValueError,
    NotImplementedOptionError,
    TooBigError,
)
from app.routing import params
from app.routing.options import per_point
from app.routing.settings import routing_settings

TABLE_ANNOTATIONS = ("duration", "distance")
MAX_INDEX_CHARS = 12  # per element of sources=, destinations=, waypoints=, timestamps=
MAX_SCALE_FACTOR = 1e6
"""table's ``scale_factor`` at most: any route's duration (under 1e9 s even across a continent)
times it stays far inside a double, where 1e308 overflowed to infinity."""
FALLBACK_SPEED = (1e-3, 1e6)
"""table's ``fallback_speed``, m/s: a crow-flies estimate (at most 2e7 m) over it stays finite."""


def _indices(name: str, raw: str, n: int) -> list[int]:
    """``i;j;...`` indices into the ``n`` points; malformed is 400 ``InvalidQuery``, an
    index out of range ``InvalidOptions`` (as OSRM)."""
    parts = params.bounded(name, raw, (MAX_INDEX_CHARS + 1) * max(n, 1) * 4).split(";")
    out = []
    for part in parts:
        value = params.integer_in(name, part, 0, 10**9) if part else -1
        if part == "" or value >= n:
            raise InvalidOptionsError(f"{name}: {part[:20]!r} is not the index of one of the "
                                      f"{n} points (0..{n - 1})")
        out.append(value)
    return out


def _count(service: str, n: int, least: int, most: int) -> None:
    if n < least:
        raise InvalidOptionsError(f"{service} needs at least {least} point"
                                  f"{'s' if least > 1 else ''}, not {n}")
    if n > most:
        raise TooBigError(f"{n} points; {service} takes at most {most}")


def _positive(name: str, raw: str, low: float, high: float) -> float:
    """A number above 0 (else OSRM's ``InvalidOptions``) within ``[low, high]`` (else
    ``InvalidValue``): the bounds keep every scaled duration finite, since a factor of 1e308
    (or a fallback speed of 1e-308 m/s) made reachable cells ``null``, OSRM's "no route"."""
    value = params.finite(name, raw)
    if value <= 0:
        raise InvalidOptionsError(f"{name} must be above 0, not {value:g}")
    return params.number_in(name, raw, low, high)


@dataclass(frozen=True)
class NearestOptions:
    """How many nearest segments to answer with."""

    number: int


def parse_nearest(raw: Mapping[str, str], n_points: int) -> NearestOptions:
    """``number`` (1 by default, at most ``max_nearest_number``) for one point."""
    if n_points != 1:
        raise InvalidOptionsError(f"nearest takes exactly one point, not {n_points}")
    most = routing_settings().max_nearest_number
    number = params.integer_in("number", raw.get("number", "1"), 0, 10**9)
    if number < 1:
        raise InvalidValueError("number must be at least 1", errors={"number": "at least 1"})
    if number > most:
        raise TooBigError(f"number={number}; at most {most}")
    return NearestOptions(number)


@dataclass(frozen=True)
class TableOptions:
    """Which rows and columns, which matrices, and how unreachable cells are estimated."""

    sources: list[int]
    destinations: list[int]
    annotations: frozenset[str]
    fallback_speed: float | None
    fallback_coordinate: str
    scale_factor: float


def parse_table(raw: Mapping[str, str], n_points: int) -> TableOptions:
    """Table options for ``n_points`` points; ``TooBig`` when sources x destinations exceeds
    ``max_table_size`` squared (OSRM's rule)."""
    limits = routing_settings()
    _count("table", n_points, 2, limits.max_table_size ** 2)
    sides = [list(range(n_points)) if raw.get(name, "all") == "all"
             else _indices(name, raw[name], n_points) for name in ("sources", "destinations")]
    cells = len(sides[0]) * len(sides[1])
    if cells > limits.max_table_size ** 2:
        raise TooBigError(f"{len(sides[0])} sources x {len(sides[1])} destinations = {cells} "
                          f"cells; at most {limits.max_table_size ** 2} "
                          f"({limits.max_table_size} x {limits.max_table_size})")
    names = params.bounded("annotations", raw.get("annotations", "duration"), 40).split(",")
    for name in names:
        params.choice("annotations", name, TABLE_ANNOTATIONS)
    if len(set(names)) != len(names):
        raise InvalidQueryError("annotations: each of duration, distance at most once")
    speed = raw.get("fallback_speed")
    return TableOptions(
        sides[0], sides[1], frozenset(names),
        _positive("fallback_speed", speed, *FALLBACK_SPEED) if speed is not None else None,
        params.choice("fallback_coordinate", raw.get("fallback_coordinate", "input"),
                      ("input", "snapped")),
        _positive("scale_factor", raw.get("scale_factor", "1"), 0.0, MAX_SCALE_FACTOR))


@dataclass(frozen=True)
class MatchOptions:
    """A trace's timestamps, how gaps split it, tidying, and which points end legs."""

    timestamps: list[int] | None
    gaps: str
    tidy: bool
    waypoints: list[int] | None


def parse_match(raw: Mapping[str, str], n_points: int) -> MatchOptions:
    """Match options for a trace of ``n_points`` points."""
    _count("match", n_points, 2, routing_settings().max_match_points)
    timestamps = None
    if raw.get("timestamps") is not None:
        parts = per_point("timestamps", raw["timestamps"], n_points, MAX_INDEX_CHARS)
        timestamps = [params.integer_in(f"timestamp of {params.point(i)}", p or "", 0,
                                        2**40) if p else -1 for i, p in enumerate(parts)]
        if -1 in timestamps:
            raise InvalidOptionsError("timestamps: give one for every point")
        back = next((i for i in range(1, n_points) if timestamps[i] < timestamps[i - 1]), None)
        if back is not None:
            message = (f"timestamps go back in time at {params.point(back)} "
                       f"({timestamps[back]} after {timestamps[back - 1]}): they must not "
                       "decrease")
            raise InvalidValueError(message, errors={"timestamps": message})
    tidy = params.boolean("tidy", raw.get("tidy", "false"))
    waypoints = None
    if raw.get("waypoints") is not None:
        waypoints = _indices("waypoints", raw["waypoints"], n_points)
        if waypoints[0] != 0 or waypoints[-1] != n_points - 1 or \
                any(b <= a for a, b in itertools.pairwise(waypoints)):
            message = ("waypoints must list point indices in increasing order, from the first "
                       f"(0) to the last ({n_points - 1})")
            raise InvalidValueError(message, errors={"waypoints": message})
        if tidy:
            message = "tidy and waypoints cannot be given together (tidying drops points)"
            raise InvalidValueError(message, errors={"waypoints": message})
    return MatchOptions(timestamps, params.choice("gaps", raw.get("gaps", "split"),
                                                  ("split", "ignore")), tidy, waypoints)


@dataclass(frozen=True)
class TripOptions:
    """Whether the trip returns to its start, and whether its ends are fixed."""

    roundtrip: bool
    fixed_start: bool
    fixed_end: bool


def parse_trip(raw: Mapping[str, str], n_points: int) -> TripOptions:
    """Trip options; an open trip with neither end fixed is OSRM's ``NotImplemented``."""
    _count("trip", n_points, 2, routing_settings().max_trip_points)
    opts = TripOptions(params.boolean("roundtrip", raw.get("roundtrip", "true")),
                       params.choice("source", raw.get("source", "any"),
                                     ("any", "first")) == "first",
                       params.choice("destination", raw.get("destination", "any"),
                                     ("any", "last")) == "last")
    if not (opts.roundtrip or opts.fixed_start or opts.fixed_end):
        raise NotImplementedOptionError("roundtrip=false needs source=first or "
                                        "destination=last (an open trip needs a fixed end)")
    return opts
