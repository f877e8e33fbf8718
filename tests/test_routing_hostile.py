"""Hostile input to the routing endpoints (issue 12's probes): every one is a clear 4xx, never a
500, a silently accepted value or an unbounded answer; and reads follow the network read role."""

from __future__ import annotations

import math
from collections.abc import Iterator

import psycopg
import pytest

from app.routing.options import SERVICES
from app.settings import get_settings
from testkit import synthetic
from testkit.network_helpers import bearer
from tests.routing_support import dsn, unique, xy

BIG = 50 * 1024 * 1024


@pytest.fixture(scope="module")
def net(database_url: str) -> Iterator[dict]:
    """A 2 km street, and a second network holding a segment that runs off the globe (deleted
    afterwards: other tests draw every network of the session's database)."""
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        name = unique("hostile")
        nid = synthetic.create_network(conn, name)
        synthetic.add_line(conn, nid, [xy(0, 0), xy(2000, 0)])
        broken = unique("offglobe")
        bid = synthetic.create_network(conn, broken)
        synthetic.add_line(conn, bid, [xy(0, 0), (200.0, 95.0)])
        a, b = xy(10, 1), xy(1990, 1)
        yield {"name": name, "broken": broken,
               "points": f"{a[0]!r},{a[1]!r};{b[0]!r},{b[1]!r}", "point": f"{a[0]!r},{a[1]!r}"}
        conn.execute("DELETE FROM networks WHERE id = %s", (bid,))


def problem(resp, status: int, code: str) -> dict:
    assert resp.status_code == status, resp.text
    body = resp.json()
    assert body["code"] == code and body["message"], body
    return body


def test_nul_byte_in_network_name_is_400(client, net) -> None:
    q = f"points={net['points']}"
    problem(client.get(f"/networks/a%00b/route?{q}"), 400, "InvalidParameterValue")
    problem(client.get(f"/networks/a%00b/isochrone?point={net['point']}&seconds=5"), 400,
            "InvalidParameterValue")
    problem(client.post("/networks/a%00b/route", json={"points": [[1.5, 42.5], [1.6, 42.5]]}),
            400, "InvalidParameterValue")
    problem(client.get(f"/networks/a%00b/route/v1/driving/{net['points']}"), 400, "InvalidUrl")


def test_nul_byte_in_avoid_is_400(client, net) -> None:
    r = client.get(f"/networks/{net['name']}/route?points={net['points']}&avoid=a%00b")
    assert "control character" in problem(r, 400, "InvalidQuery")["message"]
    r = client.post(f"/networks/{net['name']}/route",
                    json={"points": [[1.5, 42.5], [1.51, 42.5]], "avoid": ["a\x00b"]})
    problem(r, 400, "InvalidQuery")
    r = client.get(f"/networks/{net['name']}/isochrone?point={net['point']}&seconds=5"
                   "&avoid=a%00b")
    problem(r, 400, "InvalidQuery")


def test_network_with_coordinates_off_the_globe_is_a_clear_error(client, net) -> None:
    r = client.get(f"/networks/{net['broken']}/route", params={"points": net["points"]})
    body = problem(r, 422, "NoSegment")
    assert "outside lon -180..180, lat -90..90" in body["message"]
    r = client.get(f"/networks/{net['broken']}/isochrone",
                   params={"point": net["point"], "seconds": 5})
    problem(r, 422, "NoSegment")


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "NaN", "1e999", "1_0", "\u0663",
                                   "0x10", ""])
def test_non_finite_or_odd_numbers_are_refused(client, net, value) -> None:
    base = f"/networks/{net['name']}"
    iso = {"point": net["point"], "seconds": "30"}
    for url, params in (
            (f"{base}/isochrone", {**iso, "radius": value}),
            (f"{base}/isochrone", {"point": net["point"], "seconds": value}),
            (f"{base}/isochrone", {"point": net["point"], "meters": value}),
            (f"{base}/route", {"points": net["points"], "radius": value}),
            (f"{base}/route", {"points": net["points"], "format": "waypoints",
                               "spacing": value}),
            (f"{base}/route", {"points": f"{value},42.5;1.5,42.5"}),
            (f"{base}/route", {"points": net["points"], "radiuses": f"{value or 'x'};"})):
        problem(client.get(url, params=params), 400, "InvalidQuery")


def test_nan_in_a_json_body_is_refused(client, net) -> None:
    r = client.post(f"/networks/{net['name']}/route",
                    content=b'{"points": [[NaN, 42.5], [1.5, 42.5]]}',
                    headers={"content-type": "application/json"})
    problem(r, 400, "InvalidQuery")
    r = client.post(f"/networks/{net['name']}/route",
                    content=b'{"points": [[1.5, 42.5], [1.51, 42.5]], "radius": Infinity}',
                    headers={"content-type": "application/json"})
    problem(r, 400, "InvalidQuery")


@pytest.mark.parametrize(("params", "field"), [
    ({"radius": "-1"}, "radius"), ({"radius": "1e9"}, "radius"),
    ({"format": "waypoints", "spacing": "0.1"}, "spacing"),
    ({"format": "waypoints", "spacing": "1e9"}, "spacing"),
])
def test_floats_are_bounded_by_the_settings(client, net, params, field) -> None:
    r = client.get(f"/networks/{net['name']}/route", params={"points": net["points"], **params})
    assert field in problem(r, 422, "InvalidValue")["errors"]


@pytest.mark.parametrize(("params", "field"), [
    ({"seconds": "0"}, "seconds"), ({"seconds": "1e9"}, "seconds"),
    ({"meters": "-5"}, "meters"), ({"meters": "1e12"}, "meters"),
    ({"seconds": "30", "radius": "-1"}, "radius"),
])
def test_isochrone_budgets_are_bounded(client, net, params, field) -> None:
    r = client.get(f"/networks/{net['name']}/isochrone", params={"point": net["point"],
                                                                 **params})
    assert field in problem(r, 422, "InvalidValue")["errors"]


def test_dense_waypoints_are_capped(client, net, limits) -> None:
    url = f"/networks/{net['name']}/route"
    ok = client.get(url, params={"points": net["points"], "format": "waypoints",
                                 "spacing": "0.5"})
    assert ok.status_code == 200 and ok.json()["length_m"] == pytest.approx(1980, abs=0.01)
    # every 0.5 m of the 1980 m, plus the end
    assert len(ok.json()["points"]) == math.ceil(ok.json()["length_m"] / 0.5) + 1
    limits(max_waypoints=1000)
    r = client.get(url, params={"points": net["points"], "format": "waypoints", "spacing": "1"})
    assert "waypoints" in problem(r, 422, "ResponseTooLarge")["message"]
    ok = client.get(url, params={"points": net["points"], "format": "waypoints", "spacing": "2"})
    assert ok.status_code == 200


def test_route_and_isochrone_answers_are_capped(client, net, limits) -> None:
    limits(max_response_coordinates=3)
    r = client.get(f"/networks/{net['name']}/route", params={"points": net["points"]})
    problem(r, 422, "ResponseTooLarge")
    r = client.get(f"/networks/{net['name']}/route/v1/driving/{net['points']}",
                   params={"overview": "full", "steps": "true"})
    problem(r, 400, "TooBig")
    r = client.get(f"/networks/{net['name']}/isochrone",
                   params={"point": net["point"], "seconds": "600"})
    problem(r, 422, "ResponseTooLarge")


def test_huge_avoid_is_refused_early(client, net) -> None:
    """50 MB in a JSON body; in a query string as much as an HTTP client sends (httpx stops
    at 64 kB; servers cut request lines shorter still)."""
    huge = "a" * BIG
    r = client.get(f"/networks/{net['name']}/route", params={"points": net["points"],
                                                             "avoid": huge[:30_000]})
    assert "at most" in problem(r, 400, "InvalidQuery")["message"]
    r = client.post(f"/networks/{net['name']}/route",
                    json={"points": [[1.5, 42.5], [1.51, 42.5]], "avoid": huge})
    problem(r, 413, "PayloadTooLarge")  # the service-wide body limit, before any parsing
    r = client.post(f"/networks/{net['name']}/route",
                    json={"points": [[1.5, 42.5], [1.51, 42.5]], "avoid": ["a"] * 100_000})
    problem(r, 400, "InvalidQuery")
    # More points than allowed, however long the text: TooBig, as 101 points are (issue 33)
    r = client.get(f"/networks/{net['name']}/route", params={"points": "1.5,42.5;" * 3000})
    problem(r, 400, "TooBig")


def test_unknown_options_are_refused_not_ignored(client, net) -> None:
    r = client.get(f"/networks/{net['name']}/route", params={"points": net["points"],
                                                             "avoid_classes": "motorway"})
    assert "avoid_classes" in problem(r, 400, "InvalidQuery")["message"]
    r = client.post(f"/networks/{net['name']}/route",
                    json={"points": [[1.5, 42.5], [1.51, 42.5]], "speed": 5})
    problem(r, 422, "InvalidValue")
    r = client.get(f"/networks/{net['name']}/isochrone", params={"point": net["point"],
                                                                 "seconds": "5", "x": "1"})
    problem(r, 400, "InvalidQuery")


def test_read_role_covers_routes_isochrones_waypoints_and_osrm_urls(client, net,
                                                                    monkeypatch) -> None:
    """Every routing service, on both URL families, is behind the network read role."""
    base = f"/networks/{net['name']}"
    urls = [f"{base}/route?points={net['points']}",
            f"{base}/route?points={net['points']}&format=waypoints&spacing=10",
            f"{base}/isochrone?point={net['point']}&seconds=30",
            f"{base}/nearest?point={net['point']}"]
    urls += [f"{base}/{service}?points={net['points']}" for service in SERVICES
             if service != "nearest"]
    urls += [f"{base}/{service}/v1/driving/"
             f"{net['point'] if service == 'nearest' else net['points']}" for service in SERVICES]
    monkeypatch.setenv("UGVMAP_NETWORK_READ_ROLE", "viewer")
    get_settings.cache_clear()
    try:
        for url in urls:
            problem(client.get(url), 401, "Unauthorized")
        problem(client.post(f"{base}/route", json={"points": [[1.5, 42.5], [1.51, 42.5]]}),
                401, "Unauthorized")
        viewer = bearer("viewer")
        for url in urls:
            assert client.get(url, headers=viewer).status_code == 200, url
    finally:
        monkeypatch.delenv("UGVMAP_NETWORK_READ_ROLE")
        get_settings.cache_clear()
    assert all(client.get(url).status_code == 200 for url in urls)


def test_options_that_do_not_apply_are_refused(client, net) -> None:
    url = f"/networks/{net['name']}/route"
    r = client.get(url, params={"points": net["points"], "spacing": "5"})
    assert "spacing" in problem(r, 400, "InvalidOptions")["message"]
    r = client.get(url, params={"points": net["points"], "format": "waypoints",
                                "alternatives": "true"})
    assert "alternatives" in problem(r, 400, "InvalidOptions")["message"]
    r = client.post(url, json={"points": [[1.5, 42.5], [1.51, 42.5]], "point": [1, 2]})
    problem(r, 422, "InvalidValue")
    r = client.post(url, json={"points": [[10**400, 42.5], [1.51, 42.5]]})
    problem(r, 400, "InvalidQuery")
