"""Shared helpers of the routing tests: a writer connection and network names."""

from __future__ import annotations

import functools
import uuid

from app.db.session import libpq_dsn
from app.routing.geometry import local_frame


@functools.lru_cache(maxsize=8)
def _frame(origin: tuple[float, float]):
    return local_frame(*origin)


def xy(x_m: float, y_m: float, origin: tuple[float, float] = (1.5, 42.5)) -> tuple[float, float]:
    """lon/lat of the point x metres east and y metres north of ``origin`` (local aeqd frame,
    so ground distances between test points are exact to well under a millimetre)."""
    lon, lat = _frame(origin).transform(x_m, y_m, direction="INVERSE")
    return float(lon), float(lat)


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
    """Segment ids driven, in order (from each leg's ``segments``)."""
    return [s["id"] for leg in body["routes"][0]["legs"] for s in leg["segments"]]
