"""What the hostile probe of issue 33 found about requests (items 4, 8, 9, 11, 12): each one
refused in our words or answered properly now, never a 500 or a silently wrong answer."""

from __future__ import annotations

import json
from collections.abc import Iterator

import httpx
import psycopg
import pytest

from testkit import synthetic
from testkit.network_helpers import grid_network
from testkit.server import raw_exchange
from tests.routing_support import dsn, unique, xy


@pytest.fixture(scope="module")
def street(database_url: str) -> Iterator[dict]:
    """A 2 km street, and the text of a few points along it."""
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        name = unique("probe33")
        nid = synthetic.create_network(conn, name)
        synthetic.add_line(conn, nid, [xy(0, 0), xy(2000, 0)])
        pts = [xy(x, 1) for x in (10, 500, 1000, 1990)]
        yield {"name": name, "id": nid,
               "points": ";".join(f"{lon!r},{lat!r}" for lon, lat in pts),
               "two": ";".join(f"{lon!r},{lat!r}" for lon, lat in pts[:2]),
               "three": ";".join(f"{lon!r},{lat!r}" for lon, lat in pts[:3]),
               "list": [list(p) for p in pts]}


def _negative_requests(s: dict) -> list[tuple[str, str, dict | None]]:
    """The probe's requests with a negative number (method, URL, JSON body)."""
    n, one, two, three, four = (s["name"], s["points"].split(";")[0], s["two"], s["three"],
                                s["points"])
    osrm = f"/networks/{n}"
    return [
        ("GET", f"{osrm}/nearest/v1/driving/{one}?number=-1", None),
        ("GET", f"{osrm}/route/v1/driving/{two}?alternatives=-1", None),
        ("GET", f"{osrm}/route/v1/driving/{two}?bearings=-1,10;0,10", None),
        ("GET", f"{osrm}/route/v1/driving/{two}?bearings=0,-10;0,10", None),
        ("GET", f"{osrm}/table/v1/driving/{two}?sources=-1", None),
        ("GET", f"{osrm}/table/v1/driving/{three}?destinations=0;-2", None),
        ("GET", f"{osrm}/match/v1/driving/{three}?timestamps=1;2;-3", None),
        ("GET", f"{osrm}/match/v1/driving/{three}?waypoints=0;-1;2", None),
        ("GET", f"{osrm}/trip/v1/driving/{three}?bearings=-1,10;0,10;0,10", None),
        ("GET", f"{osrm}/nearest?point={one}&number=-1", None),
        ("GET", f"{osrm}/route?points={two}&alternatives=-1", None),
        ("GET", f"{osrm}/route?points={two}&bearings=-1,10;0,10", None),
        ("GET", f"{osrm}/table?points={two}&sources=-1", None),
        ("GET", f"{osrm}/match?points={three}&timestamps=1;2;-3", None),
        ("GET", f"{osrm}/trip?points={four}&bearings=-1,10;;;", None),
        ("POST", f"{osrm}/route", {"points": s["list"][:2], "alternatives": -1}),
        ("POST", f"{osrm}/route", {"points": s["list"][:2], "bearings": [[-1, 10], None]}),
        ("POST", f"{osrm}/table", {"points": s["list"][:3], "destinations": [0, -2]}),
        ("POST", f"{osrm}/match", {"points": s["list"][:3], "waypoints": [0, -1, 2]}),
        ("POST", f"{osrm}/match", {"points": s["list"][:3], "timestamps": [1, 2, -3]}),
    ]


def test_negative_numbers_are_refused_not_a_500(client, street) -> None:
    """``number=-1`` and 18 like it were a 500: formatting the refusal's range "0..inf" applied
    ``:g`` to the string ``'inf'``. Each is a 400 now, naming the option and its range."""
    for method, url, body in _negative_requests(street):
        r = client.request(method, url, json=body)
        assert r.status_code == 400, (url, body, r.status_code, r.text)
        answer = r.json()
        assert answer["code"] in ("InvalidQuery", "InvalidOptions"), (url, answer)
        assert "-1" in answer["message"] or "-2" in answer["message"] or \
            "-3" in answer["message"] or "-10" in answer["message"], (url, answer)


def test_table_scale_factor_and_fallback_speed_keep_durations_finite(client, street) -> None:
    """``scale_factor=1e308`` answered ``null`` (OSRM's "no route") for a reachable pair; a
    fallback speed of 1e-308 m/s did the same for the estimated cells. Both are bounded."""
    base = f"/networks/{street['name']}/table"
    r = client.get(base, params={"points": street["two"], "scale_factor": "1e308"})
    assert (r.status_code, r.json()["code"]) == (422, "InvalidValue"), r.text
    assert "scale_factor must be in" in r.json()["message"]
    r = client.get(f"/networks/{street['name']}/table/v1/driving/{street['two']}",
                   params={"scale_factor": "1e308"})
    assert (r.status_code, r.json()["code"]) == (400, "InvalidValue"), r.text
    r = client.get(base, params={"points": street["two"], "fallback_speed": "1e-308"})
    assert (r.status_code, r.json()["code"]) == (422, "InvalidValue"), r.text
    r = client.get(base, params={"points": street["two"], "scale_factor": "1e6"})
    durations = r.json()["durations"]
    assert all(v is not None and v > 0 for v in (durations[0][1], durations[1][0])), durations


def test_ten_thousand_coordinates_in_a_url_are_too_big(live_server, street) -> None:
    """101 coordinates were ``TooBig`` but 10,000 (a 300 kB URL) were a 400 saying the request
    was not valid HTTP/1.1. Both are OSRM's ``TooBig`` now, on both URL families."""
    lon, lat = xy(10, 1)
    many = ";".join([f"{lon:.6f},{lat:.6f}"] * 10_000)
    for path in (f"/networks/{street['name']}/route/v1/driving/{many}",
                 f"/networks/{street['name']}/route?points={many}"):
        answer = raw_exchange(live_server, f"GET {path} HTTP/1.1\r\nHost: x\r\n"
                              "Connection: close\r\n\r\n".encode())
        head, _, body = answer.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 400 "), answer[:300]
        assert json.loads(body)["code"] == "TooBig", body[:300]
    # Under the URL limit, but more text than the points allowed: TooBig too (was InvalidQuery)
    some = ";".join([f"{lon:.6f},{lat:.6f}"] * 3_000)
    r = httpx.get(f"{live_server}/networks/{street['name']}/route/v1/driving/{some}")
    assert (r.status_code, r.json()["code"]) == (400, "TooBig"), r.text[:300]


def test_unknown_query_parameters_are_refused_everywhere(client, street) -> None:
    """``lanelet2.osm?bboxx=...`` answered the whole network, and MVT tiles and TileJSON took
    any parameter, while items and routing refuse unknown ones: now all do, naming it."""
    net = f"/networks/{street['name']}"
    tilejson = client.get(f"{net}/tilejson.json")
    assert tilejson.status_code == 200, tilejson.text
    versioned_tile = tilejson.json()["tiles"][0].format(z=14, x=8260, y=6041)
    for url in (f"{net}/lanelet2.osm?bboxx=1.5,42.49,1.53,42.51",
                f"{net}/tiles/14/8260/6041.mvt?x=1", f"{net}/tiles/14/8260/6041.pbf?x=1",
                f"{versioned_tile}&x=1", f"{net}/tilejson.json?x=1", f"{net}/style.json?x=1",
                f"{net}/tiles/metadata.json?x=1", "/layers/nolayer/tilejson.json?x=1",
                "/tiles/nolayer/14/8260/6041.png?x=1"):
        r = client.get(url)
        assert (r.status_code, r.json()["code"]) == (400, "InvalidParameterValue"), url
        assert "unknown query parameter 'bboxx'" in r.json()["message"] or \
            "unknown query parameter 'x'" in r.json()["message"], (url, r.text)
    # What they do take still works.
    assert client.get(versioned_tile).status_code == 200
    r = client.get(f"{net}/lanelet2.osm", params={"bbox": "1.49,42.49,1.53,42.51",
                                                   "origin": "42.5,1.5"})
    assert r.status_code == 200, r.text
    r = client.get("/layers/nolayer/tilejson.json?format=png")
    assert (r.status_code, r.json()["code"]) == (404, "LayerNotFound")


@pytest.mark.parametrize("epsg", [3857, 32631, 4326])
def test_geometries_in_another_crs_carry_no_crs_member(client, epsg: int) -> None:
    """``?crs=...EPSG/0/32631`` put a ``crs`` member inside every geometry (PostGIS's
    ``ST_AsGeoJSON`` adds one for SRIDs other than 4326; RFC 7946 dropped it): the
    ``Content-Crs`` header says the CRS, the geometries hold type and coordinates only."""
    net = grid_network()
    crs = f"http://www.opengis.net/def/crs/EPSG/0/{epsg}"
    for kind in ("segments", "nodes"):
        items = f"/collections/{net.network}-{kind}/items"
        page = client.get(items, params={"crs": crs, "limit": 5})
        assert page.headers["content-crs"] == f"<{crs}>"
        features = page.json()["features"]
        one = client.get(f"{items}/{features[0]['id']}", params={"crs": crs})
        assert one.headers["content-crs"] == f"<{crs}>"
        for geometry in [f["geometry"] for f in features] + [one.json()["geometry"]]:
            assert set(geometry) == {"type", "coordinates"}, geometry


def test_a_segment_south_of_80s_is_reported_and_skipped_by_the_lanelet2_export(
        client, database_url: str) -> None:
    """One segment south of 80°S (an edit in EPSG:32701 puts it there) made the export of the
    whole network a 400 for everyone; it is left out and reported, as degenerate segments are."""
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        name = unique("antarctic")
        nid = synthetic.create_network(conn, name)
        kept = synthetic.add_line(conn, nid, [xy(0, 0), xy(300, 0)])
        south = synthetic.add_line(conn, nid, [(1.5, -85.0), (1.51, -85.0)])
        alone = unique("antarctic")
        synthetic.add_line(conn, synthetic.create_network(conn, alone),
                           [(1.5, -85.0), (1.51, -85.0)])
    r = client.get(f"/networks/{name}/lanelet2.osm")
    assert r.status_code == 200, r.text
    assert f"segment {south}: outside-utm" in r.text
    assert f'k="segment_id" v="{kept}"' in r.text and f'k="segment_id" v="{south}"' not in r.text
    r = client.get(f"/networks/{alone}/lanelet2.osm")
    assert (r.status_code, r.json()["code"]) == (400, "InvalidParameterValue"), r.text
    assert "outside UTM" in r.json()["message"]
