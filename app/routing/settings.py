"""Routing limits, from the environment (prefix ``UGVMAP_ROUTING_``).

Every number a client sends is bounded by one of these, and so is every answer: a request
over a limit is refused before the search (points, radii, budgets) or before the response is
built (coordinates, waypoints), so no anonymous request can make a worker allocate without
bound.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Literal

from pydantic_settings import BaseSettings, SettingsConfigDict


class RoutingSettings(BaseSettings):
    """Routing limits, from ``UGVMAP_ROUTING_*`` environment variables."""
    model_config = SettingsConfigDict(env_prefix="UGVMAP_ROUTING_", extra="ignore")

    snap_radius_m: float = 50.0  # default per point: farther from every road is NoSegment
    max_snap_radius_m: float = 10_000.0  # radius=/radiuses= ceiling; what `unlimited` means
    max_points: int = 100  # per route request: TooBig beyond
    max_optimize_points: int = 30  # optimize=true needs a cost matrix: n searches
    max_alternatives: int = 3  # alternatives=N: TooBig beyond
    max_nearest_number: int = 100  # nearest's number= (OSRM's --max-nearest-size)
    max_table_size: int = 100  # table: sources x destinations <= this squared (OSRM's rule)
    max_trip_points: int = 100  # trip (OSRM's --max-trip-size)
    max_match_points: int = 5000  # match: points of one trace (OSRM's default is 100)
    # table, match and trip stop with TooBig once their searches have taken this long
    time_budget_s: float = 10.0
    max_isochrone_seconds: float = 4 * 3600.0
    max_isochrone_meters: float = 200_000.0
    min_spacing_m: float = 0.5  # format=waypoints
    max_spacing_m: float = 10_000.0
    # Output caps: coordinates of one answer (route overviews + step geometries, or isochrone
    # lines) and dense waypoints; beyond them the answer is refused (ResponseTooLarge).
    max_response_coordinates: int = 200_000
    max_waypoints: int = 50_000
    driving_side: Literal["right", "left"] = "right"  # approaches=curb and driving_side
    # Networks with fewer segments route by Dijkstra alone: a hierarchy would not pay off.
    hierarchy_min_segments: int = 1000


@lru_cache(maxsize=1)
def routing_settings() -> RoutingSettings:
    """Read once per process (cached); tests clear the cache to try other limits."""
    return RoutingSettings()
