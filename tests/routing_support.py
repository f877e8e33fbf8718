"""Shared helpers of the routing tests: a writer connection and network names."""

from __future__ import annotations

import math
import uuid

from app.routing.live import libpq_dsn

# One degree of latitude in metres, and a metre in degrees of latitude near the test origin.
M = 1 / 111_320.0


def xy(x_m: float, y_m: float, origin: tuple[float, float] = (1.5, 42.5)) -> tuple[float, float]:
    """lon/lat of a point x metres east and y metres north of ``origin``."""
    return (origin[0] + x_m * M / math.cos(math.radians(origin[1])), origin[1] + y_m * M)


def dsn(database_url: str) -> str:
    return libpq_dsn(database_url)


def unique(prefix: str) -> str:
    return f"{prefix}-{uuid.uuid4().hex[:8]}"


def route(client, name: str, points: list[tuple[float, float]], **params) -> dict:
    q = ";".join(f"{lon!r},{lat!r}" for lon, lat in points)
    r = client.get(f"/networks/{name}/route", params={"points": q, **params})
    assert r.status_code == 200, r.text
    return r.json()


def segment_walk(body: dict) -> list[int]:
    """Segment ids driven, in order (from each leg's annotation)."""
    return [sid for leg in body["routes"][0]["legs"] for sid in leg["annotation"]["segment_ids"]]
