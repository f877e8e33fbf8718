"""Shared helpers of the routing tests: a writer connection and network names."""

from __future__ import annotations

import uuid

from app.routing.live import libpq_dsn

# One degree of latitude in metres, and a metre in degrees of latitude near the test origin.
M = 1 / 111_320.0


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
    """Segment ids of the route's steps, in order."""
    return [s["segment_id"] for leg in body["routes"][0]["legs"] for s in leg["steps"]
            if "segment_id" in s]
