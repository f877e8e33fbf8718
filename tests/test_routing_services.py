"""OSRM's nearest, table, match and trip services: every answer against OSRM's documented
schema (tests/osrm_schema.py) and against our own route answers between the same points, a
noisy trace of a known route matched back, edits reaching every service, OSRM's error codes
for bad input and limits (never a 5xx, nothing stored changed), and a third-party OSRM client
(routingpy) reading our table and routes."""

from __future__ import annotations

import itertools
import math
import random

import numpy as np
import psycopg
import pytest

from app.routing.geometry import haversine_m
from testkit import synthetic
from tests.osrm_schema import check
from tests.routing_support import dsn, unique

ORIGIN = (1.6, 42.6)  # away from the other routing tests' networks
DLAT = 100.0 / synthetic.METRES_PER_DEG_LAT
DLON = DLAT / math.cos(math.radians(ORIGIN[1]))


def at(r: float, c: float) -> tuple[float, float]:
    """lon/lat of grid position (row r, column c); fractions fall between nodes."""
    return ORIGIN[0] + c * DLON, ORIGIN[1] + r * DLAT


def coords(pts) -> str:
    return ";".join(f"{x!r},{y!r}" for x, y in pts)


@pytest.fixture(scope="module")
def writer(database_url: str):
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        yield conn


@pytest.fixture(scope="module")
def grid(writer) -> dict:
    """A 10 x 10 grid of two-way streets 100 m apart (speeds 20..70 km/h), and a separate
    200 m street 2 km east that no road joins."""
    name = unique("svc")
    net = synthetic.grid(writer, name, 10, 10, origin=ORIGIN)
    island = synthetic.add_line(writer, net, [at(0, 30), at(0, 32)])
    return {"name": name, "net": net, "island": island}


def osrm(client, name: str, service: str, pts, **params) -> dict:
    r = client.get(f"/networks/{name}/{service}/v1/driving/{coords(pts)}", params=params)
    assert r.status_code == 200, r.text
    return check(r.json(), service)


def fault(resp, code: str, status: int = 400) -> dict:
    assert resp.status_code == status, resp.text
    body = check(resp.json(), "error")
    assert body["code"] == code, resp.text
    return body


POINTS = [at(0.3, 0.02), at(4.6, 2.97), at(8.02, 7.4), at(2.5, 8.97), at(6.03, 5.5)]


# -- schema, both URL families ---------------------------------------------------------------
def test_every_service_answers_in_osrm_schema_on_both_url_families(client, grid) -> None:
    name = grid["name"]
    osrm(client, name, "route", POINTS[:2], steps="true", annotations="true")
    osrm(client, name, "nearest", POINTS[:1], number=3)
    osrm(client, name, "table", POINTS, annotations="duration,distance")
    osrm(client, name, "trip", POINTS, steps="true")
    osrm(client, name, "match", [at(0.02, k / 4) for k in range(12)], steps="true",
         annotations="true", geometries="geojson")
    own = {"nearest": {"point": coords(POINTS[:1])}, "table": {"points": coords(POINTS)},
           "trip": {"points": coords(POINTS)},
           "match": {"points": coords(at(0.02, k / 4) for k in range(12))}}
    for service, params in own.items():
        r = client.get(f"/networks/{name}/{service}", params=params)
        assert r.status_code == 200, r.text
        check(r.json(), service)
    trip = client.get(f"/networks/{name}/trip", params=own["trip"]).json()
    assert trip["trips"][0]["geometry"]["type"] == "LineString"  # our defaults: GeoJSON, steps
    assert trip["trips"][0]["legs"][0]["steps"]


def test_post_bodies_take_json_lists(client, grid) -> None:
    name = grid["name"]
    body = {"points": [list(p) for p in POINTS], "sources": [0, 1], "annotations": ["distance"]}
    r = client.post(f"/networks/{name}/table", json=body)
    table = check(r.json(), "table")
    assert len(table["distances"]) == 2 and "durations" not in table
    trace = [list(at(0.02, k / 4)) for k in range(12)]
    r = client.post(f"/networks/{name}/match", json={"points": trace,
                                                     "timestamps": list(range(0, 120, 10)),
                                                     "radiuses": [5] * 12})
    check(r.json(), "match")
    r = client.post(f"/networks/{name}/trip", json={"points": [list(p) for p in POINTS],
                                                    "roundtrip": False, "source": "first",
                                                    "destination": "last"})
    check(r.json(), "trip")
    r = client.post(f"/networks/{name}/table", json={"points": trace, "colour": "red"})
    assert r.status_code == 422 and r.json()["code"] == "InvalidValue"


# -- against our own answers -----------------------------------------------------------------
def test_nearest_is_the_routes_snapped_waypoint(client, grid) -> None:
    name = grid["name"]
    for p in POINTS:
        near = osrm(client, name, "nearest", [p], number=4)["waypoints"]
        route = osrm(client, name, "route", [p, POINTS[0]])["waypoints"][0]
        assert near[0]["location"] == route["location"]
        assert near[0]["segment_id"] == route["segment_id"]
        assert near[0]["distance"] == pytest.approx(route["distance"])
        assert [w["distance"] for w in near] == sorted(w["distance"] for w in near)
        assert len({w["segment_id"] for w in near}) == 4
    # A point 5 m off a street 30 m from a node: the vertex ids around it are the street's ends.
    ends = osrm(client, name, "nearest", [at(0.05, 0.3)])["waypoints"][0]["nodes"]
    row = osrm(client, name, "route", [at(0.05, 0.3), at(0.05, 0.8)],
               annotations="nodes")["routes"][0]["legs"][0]["annotation"]["nodes"]
    assert ends == row[:2]


def test_segments_meeting_at_the_nearest_vertex_tie_and_go_by_id(client, grid) -> None:
    """A point north-east of a grid node: the streets leaving the node east and north pass
    nearer; the two leaving it west and south are nearest at the node itself, at one
    distance (each reaches the node as a different end, which floating point rounds apart:
    ties are to the micrometre), and come in the order of their ids."""
    near = osrm(client, grid["name"], "nearest", [at(3.2, 4.3)], number=4)["waypoints"]
    distances = [w["distance"] for w in near]
    assert distances[0] < distances[1] < distances[2] == distances[3]
    assert near[2]["segment_id"] < near[3]["segment_id"]
    assert near[2]["location"] == near[3]["location"]


def test_table_cells_are_the_routes_between_the_points(client, grid) -> None:
    name = grid["name"]
    table = osrm(client, name, "table", POINTS, annotations="duration,distance")
    for i, a in enumerate(POINTS):
        for j, b in enumerate(POINTS):
            if i == j:
                assert table["durations"][i][j] == 0 and table["distances"][i][j] == 0
                continue
            route = osrm(client, name, "route", [a, b])["routes"][0]
            # to 0.1 s and 0.1 m, as OSRM writes tables
            assert table["durations"][i][j] == pytest.approx(route["duration"], abs=0.05)
            assert table["distances"][i][j] == pytest.approx(route["distance"], abs=0.05)
    part = osrm(client, name, "table", POINTS, sources="3;1", destinations="0;4",
                scale_factor="2")
    assert [w["location"] for w in part["sources"]] == \
        [table["sources"][3]["location"], table["sources"][1]["location"]]
    assert [v for row in part["durations"] for v in row] == pytest.approx(
        [2 * table["durations"][s][d] for s in (3, 1) for d in (0, 4)], abs=0.11)
    assert "distances" not in part  # annotations=duration by default


def test_table_through_the_hierarchy_equals_routes(client, writer, limits, monkeypatch) -> None:
    """Durations alone come from one many-to-many call of the contraction hierarchy (checked
    by counting its calls), quantised like its routes; distances from per-source trees."""
    from app.routing.costs import Cost
    from app.routing.hierarchy import Metric
    from tests.test_routing_hierarchy import hierarchy_ready

    limits(hierarchy_min_segments=50)
    name = unique("svch")
    net = synthetic.grid(writer, name, 10, 10, origin=(1.7, 42.7))
    hierarchy_ready(client, name, net, Cost.TIME)
    calls = []
    many = Metric.many_to_many
    monkeypatch.setattr(Metric, "many_to_many",
                        lambda self, *a: calls.append(1) or many(self, *a))
    pts = [(1.7 + (x - 1.6) * 1.0, 42.7 + (y - 42.6)) for x, y in POINTS[:4]]
    table = osrm(client, name, "table", pts)
    assert len(calls) == 1
    both = osrm(client, name, "table", pts, annotations="duration,distance")
    assert len(calls) == 1
    for i, a in enumerate(pts):
        for j, b in enumerate(pts):
            route = osrm(client, name, "route", [a, b])["routes"][0] if i != j else \
                {"duration": 0.0, "distance": 0.0}
            assert table["durations"][i][j] == pytest.approx(route["duration"], abs=0.05)
            assert both["durations"][i][j] == pytest.approx(route["duration"], abs=0.05)
            assert both["distances"][i][j] == pytest.approx(route["distance"], abs=0.05)


def test_table_fallback_speed_estimates_unreachable_cells(client, grid) -> None:
    name = grid["name"]
    pts = [POINTS[0], at(0.03, 31)]  # the island
    plain = osrm(client, name, "table", pts)
    assert plain["durations"][0][1] is None and plain["durations"][1][0] is None
    assert "fallback_speed_cells" not in plain
    est = osrm(client, name, "table", pts, fallback_speed="10", annotations="duration,distance")
    assert est["fallback_speed_cells"] == [[0, 1], [1, 0]]
    crow = haversine_m(pts[0], pts[1])
    assert est["durations"][0][1] == pytest.approx(crow / 10, abs=0.05)  # not OSRM's #6584
    assert est["distances"][1][0] == pytest.approx(crow, abs=0.05)
    snapped = osrm(client, name, "table", pts, fallback_speed="10",
                   fallback_coordinate="snapped")
    a, b = (w["location"] for w in snapped["sources"])
    assert snapped["durations"][0][1] == pytest.approx(haversine_m(a, b) / 10, abs=0.05)


def test_trip_equals_optimize_and_round_trips_return(client, grid) -> None:
    name = grid["name"]
    pts = [*POINTS, at(1.5, 6.03), at(7.97, 1.5)]
    trip = osrm(client, name, "trip", pts, roundtrip="false", source="first",
                destination="last")
    best = osrm(client, name, "route", pts, optimize="true")
    assert [w["waypoint_index"] for w in trip["waypoints"]] == \
        [w["waypoint_index"] for w in best["waypoints"]]
    assert trip["trips"][0]["duration"] == pytest.approx(best["routes"][0]["duration"])
    assert all(w["trips_index"] == 0 for w in trip["waypoints"])
    ring = osrm(client, name, "trip", pts)  # roundtrip from the first point
    assert len(ring["trips"][0]["legs"]) == len(pts)
    assert ring["waypoints"][0]["waypoint_index"] == 0
    order = sorted(range(len(pts)), key=lambda i: ring["waypoints"][i]["waypoint_index"])
    legs = [osrm(client, name, "route", [pts[a], pts[b]])["routes"][0]["duration"]
            for a, b in zip(order, [*order[1:], order[0]], strict=True)]
    assert ring["trips"][0]["duration"] == pytest.approx(sum(legs))
    back = osrm(client, name, "route", [pts[-1], pts[0]])["routes"][0]["duration"]
    assert ring["trips"][0]["duration"] <= best["routes"][0]["duration"] + back + 1e-6
    last = osrm(client, name, "trip", pts, destination="last")  # OSRM starts it at the last
    assert last["waypoints"][-1]["waypoint_index"] == 0


# -- match -----------------------------------------------------------------------------------
def _trace(line: list[list[float]], every_m: float, noise_m: float, seed: int
           ) -> list[tuple[float, float]]:
    """Points every ``every_m`` along ``line`` with Gaussian noise of ``noise_m``."""
    rng = random.Random(seed)
    xy = np.array(line)
    step = np.array([haversine_m(tuple(a), tuple(b)) for a, b in itertools.pairwise(xy)])
    along = np.concatenate([[0.0], np.cumsum(step)])
    out = []
    for s in np.arange(0.0, along[-1], every_m):
        lon, lat = np.interp(s, along, xy[:, 0]), np.interp(s, along, xy[:, 1])
        out.append((float(lon) + rng.gauss(0, noise_m) * DLON / 100,
                    float(lat) + rng.gauss(0, noise_m) * DLAT / 100))
    return out


@pytest.mark.parametrize(("start", "end", "seed"), [
    ((0.5, 0.02), (9, 8.5), 7), ((8.97, 0.5), (0.5, 9.03), 11), ((4.5, 0.03), (5.5, 8.97), 23)])
def test_match_recovers_a_noisy_subsampled_route(client, grid, start, end, seed) -> None:
    name = grid["name"]
    route = osrm(client, name, "route", [at(*start), at(*end)], overview="full",
                 geometries="geojson")["routes"][0]
    driven = {s["id"] for leg in route["legs"] for s in leg["segments"]}
    trace = _trace(route["geometry"]["coordinates"], every_m=35, noise_m=4, seed=seed)
    body = osrm(client, name, "match", trace, overview="full", geometries="geojson",
                timestamps=";".join(str(3 * k) for k in range(len(trace))))
    assert len(body["matchings"]) == 1
    matched = body["matchings"][0]
    found = {s["id"] for leg in matched["legs"] for s in leg["segments"]}
    assert len(found & driven) >= 0.9 * len(driven)
    assert len(found - driven) <= 0.1 * len(found)
    assert matched["distance"] == pytest.approx(route["distance"], rel=0.1)
    assert matched["confidence"] > 0.5
    points = [t for t in body["tracepoints"] if t is not None]
    assert len(points) >= 0.9 * len(trace)
    assert [t["waypoint_index"] for t in points] == list(range(len(points)))
    assert len(matched["legs"]) == len(points) - 1


def test_match_splits_at_gaps_and_keeps_only_waypoints(client, grid) -> None:
    name = grid["name"]
    trace = [at(0.02, k / 4) for k in range(16)]
    times = [10 * k for k in range(8)] + [10_000 + 10 * k for k in range(8)]
    split = osrm(client, name, "match", trace, timestamps=";".join(map(str, times)))
    assert len(split["matchings"]) == 2
    assert {t["matchings_index"] for t in split["tracepoints"][8:]} == {1}
    whole = osrm(client, name, "match", trace, timestamps=";".join(map(str, times)),
                 gaps="ignore", waypoints="0;5;15")
    assert len(whole["matchings"]) == 1 and len(whole["matchings"][0]["legs"]) == 2
    assert [t["waypoint_index"] for t in whole["tracepoints"] if t is not None].count(None) == 13
    tidy = osrm(client, name, "match", [at(0.02, k / 40) for k in range(40)], tidy="true")
    assert sum(t is None for t in tidy["tracepoints"]) > 20


# -- live edits ------------------------------------------------------------------------------
def test_edits_reach_every_service(client, grid, writer) -> None:
    name = grid["name"]
    far = at(12, 3)  # 200 m north of the grid: nothing within 50 m yet
    r = client.get(f"/networks/{name}/nearest/v1/driving/{coords([far])}",
                   params={"radiuses": "50"})
    fault(r, "NoSegment")
    new = synthetic.add_line(writer, grid["net"], [at(12, 2), at(12, 4)])
    near = osrm(client, name, "nearest", [far], radiuses="50")
    assert near["waypoints"][0]["segment_id"] == new
    a, b = at(0.02, 0.5), at(0.02, 2.5)
    before = osrm(client, name, "table", [a, b])["durations"][0][1]
    trip_before = osrm(client, name, "trip", [a, b])["trips"][0]["duration"]
    seg = osrm(client, name, "route", [a, b])["routes"][0]["legs"][0]["segments"][1]["id"]
    writer.execute("UPDATE road_segments SET speed_limit_kph = 3 WHERE id = %s", (seg,))
    try:
        after = osrm(client, name, "table", [a, b])["durations"][0][1]
        assert after > before + 10
        assert osrm(client, name, "trip", [a, b])["trips"][0]["duration"] > trip_before + 10
        matched = osrm(client, name, "match", [at(0.02, k / 4) for k in range(12)])
        assert seg in {s["id"] for leg in matched["matchings"][0]["legs"]
                       for s in leg["segments"]}  # still driven: the trace says so
    finally:
        writer.execute("UPDATE road_segments SET speed_limit_kph = 50 WHERE id = %s", (seg,))


# -- bad input and limits --------------------------------------------------------------------
BAD = [
    ("nearest", [POINTS[0], POINTS[1]], {}, "InvalidOptions"),
    ("nearest", [(1.6, math.nan)], {}, "InvalidQuery"),
    ("table", [POINTS[0], (math.inf, 42.6)], {}, "InvalidQuery"),
    ("match", [POINTS[0], (1.6, math.nan)], {}, "InvalidQuery"),
    ("trip", [POINTS[0], (1.6, 95.0)], {}, "InvalidValue"),
    ("nearest", [POINTS[0]], {"number": "0"}, "InvalidValue"),
    ("nearest", [POINTS[0]], {"number": "101"}, "TooBig"),
    ("nearest", [POINTS[0]], {"number": "x"}, "InvalidQuery"),
    ("nearest", [at(300, 300)], {}, "NoSegment"),
    ("table", [POINTS[0]], {}, "InvalidOptions"),
    ("table", POINTS, {"sources": "0;9"}, "InvalidOptions"),
    ("table", POINTS, {"sources": "0;a"}, "InvalidQuery"),
    ("table", POINTS, {"annotations": "speed"}, "InvalidQuery"),
    ("table", POINTS, {"fallback_speed": "0"}, "InvalidOptions"),
    ("table", POINTS, {"fallback_speed": "nan"}, "InvalidQuery"),
    ("table", POINTS, {"scale_factor": "-1"}, "InvalidOptions"),
    ("table", POINTS, {"fallback_coordinate": "moon"}, "InvalidQuery"),
    ("table", [POINTS[0], at(300, 300)], {}, "NoSegment"),
    ("match", [POINTS[0]], {}, "InvalidOptions"),
    ("match", POINTS, {"timestamps": "5;4;6;7;8"}, "InvalidValue"),
    ("match", POINTS, {"timestamps": "1;2;3"}, "InvalidOptions"),
    ("match", POINTS, {"timestamps": "1;2;x;4;5"}, "InvalidQuery"),
    ("match", POINTS, {"waypoints": "1;4"}, "InvalidValue"),
    ("match", POINTS, {"waypoints": "0;4", "tidy": "true"}, "InvalidValue"),
    ("match", POINTS, {"gaps": "sometimes"}, "InvalidQuery"),
    ("match", POINTS, {"radius": "5"}, "InvalidQuery"),
    ("match", [at(300, 300), at(300, 301)], {}, "NoSegment"),
    ("trip", [POINTS[0]], {}, "InvalidOptions"),
    ("trip", POINTS, {"roundtrip": "false"}, "NotImplemented"),
    ("trip", POINTS, {"source": "middle"}, "InvalidQuery"),
    ("trip", [POINTS[0], at(0.03, 31)], {}, "NoTrips"),
    ("route", POINTS[:2], {"tidy": "true"}, "InvalidQuery"),
]


@pytest.mark.parametrize(("service", "pts", "params", "code"), BAD)
def test_bad_input_gets_osrms_codes_and_changes_nothing(client, grid, writer, service, pts,
                                                        params, code) -> None:
    name = grid["name"]
    version = writer.execute("SELECT version FROM networks WHERE id = %s",
                             (grid["net"],)).fetchone()
    r = client.get(f"/networks/{name}/{service}/v1/driving/{coords(pts)}", params=params)
    fault(r, code)
    own = {"nearest": "point"}.get(service, "points")
    r = client.get(f"/networks/{name}/{service}", params={own: coords(pts), **params})
    assert r.status_code in (400, 422) and r.json()["code"] == code, r.text
    assert writer.execute("SELECT version FROM networks WHERE id = %s",
                          (grid["net"],)).fetchone() == version


def test_limits_are_too_big(client, grid, limits) -> None:
    name = grid["name"]
    limits(max_table_size=2, max_trip_points=3, max_match_points=4, max_nearest_number=2)
    fault(client.get(f"/networks/{name}/table/v1/driving/{coords(POINTS)}",
                     params={"sources": "0;1;2", "destinations": "0;1"}), "TooBig")
    ok = osrm(client, name, "table", POINTS[:4], sources="0;1", destinations="2;3")
    assert len(ok["durations"]) == 2
    fault(client.get(f"/networks/{name}/trip/v1/driving/{coords(POINTS)}"), "TooBig")
    fault(client.get(f"/networks/{name}/match/v1/driving/{coords(POINTS)}"), "TooBig")
    fault(client.get(f"/networks/{name}/nearest/v1/driving/{coords(POINTS[:1])}",
                     params={"number": "3"}), "TooBig")
    limits(time_budget_s=0)
    fault(client.get(f"/networks/{name}/match/v1/driving/{coords(POINTS[:3])}"), "TooBig")


# -- a client nobody here wrote ----------------------------------------------------------------
def test_routingpy_reads_our_routes_and_tables(live_server, grid) -> None:
    from routingpy import OSRM

    api = OSRM(base_url=f"{live_server}/networks/{grid['name']}")
    locations = [list(p) for p in POINTS]
    matrix = api.matrix(locations, profile="driving", annotations=["duration", "distance"])
    direction = api.directions(locations[:2], profile="driving", geometries="geojson",
                               overview="full")
    # routingpy reads a route's duration and distance as whole numbers
    assert direction.duration == pytest.approx(matrix.durations[0][1], abs=1)
    assert direction.distance == pytest.approx(matrix.distances[0][1], abs=1)
    assert len(direction.geometry) >= 2 and direction.geometry[0] == pytest.approx(
        list(POINTS[0]), abs=1e-3)
    part = api.matrix(locations, profile="driving", sources=[0], destinations=[1, 2],
                      annotations=["duration"])
    assert part.durations[0] == pytest.approx(matrix.durations[0][1:3])
    from routingpy.exceptions import RouterApiError

    with pytest.raises(RouterApiError) as err:
        api.matrix([list(POINTS[0]), [1.0, 10.0]], profile="driving")
    assert err.value.status == 400 and "NoSegment" in str(err.value.message)
