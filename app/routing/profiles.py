"""Vehicle profiles: what a vehicle may drive on, decided in one place.

A network holds every way it was given (an OSM import keeps footways, cycleways and steps:
a sidewalk robot needs them, a map reviewer wants to see them), so *which* of them a route may
use is a property of the vehicle asking, not of the network. Without it a road vehicle was
routed over footways and cycleways by default (issue 34: 440 m of a 796 m Helsinki route on
footways). A profile names the road classes its vehicle never drives; every routing service
(route, nearest, table, match, trip, isochrone) leaves them out exactly like an ``avoid=``
list, so snapping, the search, the hierarchy's metrics and the "no road joins them" message
all see the same roads.

OSRM's ``car.lua`` is the reference for ``car``: it drives the ``highway=*`` values of its
speed table (motorway .. service, living_street) and none of footway, cycleway, path,
pedestrian, steps, bridleway, corridor, busway, bus_guideway, raceway, escape. One deliberate
difference: ``track`` is allowed (unpaved tracks are where ground vehicles work; ``exclude=track``
leaves them out). A class no profile names (a custom class of a GeoJSON import) is drivable:
the lists say what is *forbidden*, so unknown data is never silently unroutable.

This module is where a vehicle is described. Off road (issue 37, :class:`OffroadSettings`) it
says what the vehicle can climb and how fast it goes there (maximum slope and step, off-road
speed as a function of slope); a request may override the numbers (``max_slope=``,
``max_step=``) and name the layers that forbid (``forbid=``). The road routing code reads a
profile only through :meth:`VehicleProfile.forbids` and :attr:`VehicleProfile.forbidden`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from app.errors import InvalidValueError

# Classes that carry no motor traffic at all (OSM highway values; app.network.validation's
# ROAD_CLASSES holds the same names).
_NOT_FOR_CARS = ("footway", "cycleway", "path", "pedestrian", "steps", "bridleway", "corridor",
                 "busway", "bus_guideway", "raceway", "escape")


@dataclass(frozen=True)
class OffroadSettings:
    """What a vehicle can drive off road (issue 37): the steepest slope it climbs (or
    descends), the highest step it crosses, and its speed as a function of slope.

    ``speeds`` are (slope in degrees, km/h) stops, linear between them and flat beyond the
    last up to ``max_slope_deg``; steeper is never driven. A step is an object on the ground
    (DSM - DTM, where the surface layer is given) or, from a DEM alone, a cell's height
    above or below the median of its 3 x 3 neighbourhood (a boulder, a bank, a ditch), which
    is 0 on any plane however steep. Speeds depend on the slope's size only, not on the
    direction of travel, so a route costs the same both ways.
    """

    max_slope_deg: float
    max_step_m: float
    speeds: tuple[tuple[float, float], ...]

    def speed_kph(self, slope_deg: np.ndarray) -> np.ndarray:
        """Off-road speed at each slope (NaN slope: 0); 0 beyond :attr:`max_slope_deg`."""
        stops = np.array([s for s, _ in self.speeds])
        kph = np.array([v for _, v in self.speeds])
        speed = np.interp(np.nan_to_num(slope_deg, nan=np.inf), stops, kph)
        return np.where(np.nan_to_num(slope_deg, nan=np.inf) <= self.max_slope_deg, speed, 0.0)

    def key(self) -> tuple[float, float, tuple[tuple[float, float], ...]]:
        """What a cost surface depends on (its cache key)."""
        return (self.max_slope_deg, self.max_step_m, self.speeds)


@dataclass(frozen=True)
class VehicleProfile:
    """One kind of vehicle: its name, what it is, the road classes it never drives, and what
    it can drive off road."""

    name: str
    title: str  # in words, for lists and the web map
    forbidden: frozenset[str]  # road_class values this vehicle never drives
    offroad: OffroadSettings = OffroadSettings(20.0, 0.3, ((0.0, 20.0), (10.0, 12.0),
                                                           (20.0, 4.0)))

    def forbids(self, road_class: str) -> bool:
        """Whether this vehicle may never drive a segment of ``road_class``."""
        return road_class in self.forbidden

    def describe(self) -> str:
        """One line: the name, what it is, what it never drives."""
        return f"{self.name}: {self.title}; never on {', '.join(sorted(self.forbidden))}"


# Off road, a car-sized UGV climbs 20 degrees (a 36 % grade: what 4x4 tracks are built to)
# and crosses 0.3 m steps, at 20 km/h on the flat; the sidewalk robot 12 degrees (a 21 %
# grade, steeper than any accessible ramp) and 0.1 m (a kerb) at walking pace.
CAR = VehicleProfile(
    "car", "a road vehicle (OSRM's car profile)", frozenset(_NOT_FOR_CARS))
SIDEWALK = VehicleProfile(
    "sidewalk", "a small wheeled robot that drives on sidewalks, footways and quiet streets",
    frozenset({"motorway", "motorway_link", "trunk", "trunk_link", "steps", "busway",
               "bus_guideway", "raceway", "escape"}),
    OffroadSettings(12.0, 0.1, ((0.0, 5.0), (12.0, 2.0))))
PROFILES: dict[str, VehicleProfile] = {p.name: p for p in (CAR, SIDEWALK)}
# Other names clients send for the same vehicles: OSRM's demo server and its clients (Leaflet
# Routing Machine, routingpy) ask for ``driving``.
ALIASES: dict[str, str] = {"driving": "car", "robot": "sidewalk"}
DEFAULT = CAR  # what a request that names no profile drives: never footways


def profile_named(name: str | None, field: str = "profile") -> VehicleProfile:
    """The profile ``name`` (or an alias of it; :data:`DEFAULT` for ``None``), else 422
    ``InvalidValue`` listing the profiles: an unknown vehicle is never routed as some other."""
    if name is None:
        return DEFAULT
    found = PROFILES.get(ALIASES.get(name, name))
    if found is None:
        names = ", ".join(f"{p} (or {a})" if (a := _alias_of(p)) else p for p in PROFILES)
        message = f"profile {name[:40]!r} is unknown; the profiles are {names}"
        raise InvalidValueError(message, errors={field: message})
    return found


def _alias_of(name: str) -> str | None:
    return next((a for a, p in ALIASES.items() if p == name), None)


def usage_report(class_counts: Mapping[str, int]) -> str:
    """Which profile may use how much of a network, from its segment count per road class:
    the import's line saying that it kept every way and who may drive which, e.g.
    ``profiles: car may drive 812 of 1,024 segments (not 150 footway, 62 steps); sidewalk
    1,024``."""
    total = sum(class_counts.values())
    parts: list[str] = []
    for p in PROFILES.values():
        barred = sorted(((n, c) for c, n in class_counts.items() if p.forbids(c)),
                        key=lambda nc: (-nc[0], nc[1]))
        usable = total - sum(n for n, _ in barred)
        lead = f"{p.name} may drive {usable:,} of {total:,} segments" if not parts else (
            f"{p.name} {usable:,}")
        parts.append(lead + (f" (not {', '.join(f'{n:,} {c}' for n, c in barred)})"
                             if barred else ""))
    return f"profiles: {'; '.join(parts)}"
