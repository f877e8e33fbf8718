"""Shared helpers of the routing tests: a writer connection and network names."""

from __future__ import annotations

import functools
import uuid

from app.db.session import libpq_dsn
from app.routing.geometry import local_frame
from tests.osrm_schema import check


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
    body = r.json()
    if params.get("format") != "waypoints":  # else not an OSRM answer
        check(body, "route")
    return body


def segment_walk(body: dict) -> list[int]:
    """Segment ids driven, in order (from each leg's ``segments``)."""
    return [s["id"] for leg in body["routes"][0]["legs"] for s in leg["segments"]]


def town(conn, name: str) -> dict:
    """A small town for guidance tests (metres east/north of (1.5, 42.5)).

    Main Street (0,0)->(200,0) runs on as High Street to (400,0); Church Lane turns north there
    to a one-way roundabout (OSM ``junction=roundabout``, centre (400,250), radius 50, driven
    anticlockwise S->E->N->W) with exits East Road (east from E), North Road (north from N)
    and West Road (west from W).
    """
    from psycopg.types.json import Jsonb

    from testkit import synthetic

    net = synthetic.create_network(conn, name)
    add = synthetic.add_line
    seg = {
        "main": add(conn, net, [xy(0, 0), xy(200, 0)], name="Main Street"),
        "high": add(conn, net, [xy(200, 0), xy(400, 0)], name="High Street"),
        "church": add(conn, net, [xy(400, 0), xy(400, 200)], name="Church Lane"),
        "east": add(conn, net, [xy(450, 250), xy(650, 250)], name="East Road"),
        "north": add(conn, net, [xy(400, 300), xy(400, 500)], name="North Road"),
        "west": add(conn, net, [xy(350, 250), xy(150, 250)], name="West Road"),
    }
    ring = [(400, 200), (450, 250), (400, 300), (350, 250)]
    for k, (a, b) in enumerate(zip(ring, ring[1:] + ring[:1], strict=True)):
        mid = ((a[0] + b[0]) / 2 - 400, (a[1] + b[1]) / 2 - 250)
        bulge = (400 + mid[0] * 1.41, 250 + mid[1] * 1.41)  # on the circle, between a and b
        seg[f"ring{k}"] = add(conn, net, [xy(*a), xy(*bulge), xy(*b)], oneway="forward",
                              attrs=Jsonb({"junction": "roundabout"}))
    return {"name": name, "net": net, "seg": seg}
