"""Routing limits, from the environment (prefix ``UGVMAP_ROUTING_``)."""

from __future__ import annotations

from functools import lru_cache

from pydantic_settings import BaseSettings, SettingsConfigDict


class RoutingSettings(BaseSettings):
    """Routing limits, from ``UGVMAP_ROUTING_*`` environment variables."""
    model_config = SettingsConfigDict(env_prefix="UGVMAP_ROUTING_", extra="ignore")

    snap_radius_m: float = 50.0  # farther than this from every road: 422 NoSegmentError
    max_points: int = 100  # per route request: 400 TooBigError beyond
    max_optimize_points: int = 30  # optimize=true needs a cost matrix: n searches
    max_isochrone_seconds: float = 4 * 3600.0
    max_isochrone_meters: float = 200_000.0
    min_spacing_m: float = 0.1  # format=waypoints
    # Networks with fewer segments route by Dijkstra alone: a hierarchy would not pay off.
    hierarchy_min_segments: int = 1000


@lru_cache(maxsize=1)
def routing_settings() -> RoutingSettings:
    """Read once per process (cached); tests clear the cache to try other limits."""
    return RoutingSettings()
