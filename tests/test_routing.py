"""Route endpoint on synthetic networks with known answers: snapping, one-way, errors, shape."""

from __future__ import annotations

import polyline
import psycopg
import pytest

from testkit import synthetic
from tests.routing_support import dsn, route, segment_walk, unique, xy

LAT0 = 42.5


@pytest.fixture(scope="module")
def writer(database_url: str):
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        yield conn


@pytest.fixture(scope="module")
def block(writer) -> dict:
    """A 200 m × 100 m block: south street one-way eastbound, the rest two-way.

    (0,100) ---- n ---- (200,100)
       |                    |
       w                    e
       |                    |
    (0,0) -- s (one-way →) -- (200,0)
    """
    name = unique("block")
    net = synthetic.create_network(writer, name)
    seg = {
        "s": synthetic.add_line(writer, net, [xy(0, 0), xy(200, 0)], oneway="forward"),
        "e": synthetic.add_line(writer, net, [xy(200, 0), xy(200, 100)]),
        "n": synthetic.add_line(writer, net, [xy(200, 100), xy(0, 100)]),
        "w": synthetic.add_line(writer, net, [xy(0, 100), xy(0, 0)]),
    }
    return {"name": name, "seg": seg}


def test_point_beside_middle_routes_from_projection(client, block) -> None:
    # 8 m south of the one-way street at x=50, to 8 m south of it at x=150: straight along it.
    body = route(client, block["name"], [xy(50, -8), xy(150, -8)], cost="distance")
    r = body["routes"][0]
    assert r["distance"] == pytest.approx(100.0, abs=0.5)
    assert segment_walk(body) == [block["seg"]["s"]]
    start = body["waypoints"][0]
    assert start["distance"] == pytest.approx(8.0, abs=0.05)
    assert start["location"][0] == pytest.approx(xy(50, 0)[0], abs=2e-7)
    assert start["location"][1] == pytest.approx(LAT0, abs=2e-7)
    coords = r["geometry"]["coordinates"]
    assert coords[0] == start["location"] and coords[-1] == body["waypoints"][1]["location"]


def test_one_way_is_obeyed_on_the_snapped_segment(client, block) -> None:
    # From x=150 back to x=50 on the eastbound street: must go round the block
    # (50 m east + 100 up + 200 west + 100 down + 50 east = 500 m).
    body = route(client, block["name"], [xy(150, -5), xy(50, -5)], cost="distance")
    assert body["routes"][0]["distance"] == pytest.approx(500.0, abs=1.0)
    seg = block["seg"]
    assert segment_walk(body) == [seg["s"], seg["e"], seg["n"], seg["w"], seg["s"]]
    steps = body["routes"][0]["legs"][0]["steps"]
    assert [s["maneuver"]["type"] for s in steps] == ["depart", "turn", "turn", "turn", "turn",
                                                      "arrive"]
    # Anticlockwise round the block: every turn is a left.
    assert [s["maneuver"]["modifier"] for s in steps[1:5]] == ["left"] * 4


def test_point_on_wrong_side_of_one_way_still_obeys_direction(client, block) -> None:
    # Points just inside the block (north of the one-way street) still snap to it.
    body = route(client, block["name"], [xy(120, 3), xy(80, 3)], cost="distance")
    assert body["routes"][0]["distance"] == pytest.approx(560.0, abs=1.0)
    forward = route(client, block["name"], [xy(80, 3), xy(120, 3)], cost="distance")
    assert forward["routes"][0]["distance"] == pytest.approx(40.0, abs=0.5)


def test_two_way_street_allows_reverse(client, block) -> None:
    body = route(client, block["name"], [xy(150, 104), xy(50, 104)], cost="distance")
    assert body["routes"][0]["distance"] == pytest.approx(100.0, abs=0.5)
    step = body["routes"][0]["legs"][0]["steps"][0]
    assert step["segment_ids"] == [block["seg"]["n"]] and step["lanes"] == 1


def test_same_point_twice_is_an_empty_route(client, block) -> None:
    body = route(client, block["name"], [xy(60, -4), xy(60, -4)])
    assert body["routes"][0]["distance"] == 0 and segment_walk(body) == []
    assert body["routes"][0]["legs"][0]["steps"][-1]["maneuver"]["type"] == "arrive"


def test_polyline_matches_geojson(client, block) -> None:
    pts = [xy(150, -5), xy(50, -5)]
    gj = route(client, block["name"], pts)["routes"][0]["geometry"]["coordinates"]
    pl = route(client, block["name"], pts, geometries="polyline")["routes"][0]["geometry"]
    decoded = polyline.decode(pl, 5)
    assert len(decoded) == len(gj)
    for (lat, lon), (x, y) in zip(decoded, gj, strict=True):
        assert lat == pytest.approx(y, abs=1e-5) and lon == pytest.approx(x, abs=1e-5)


def test_post_body_equals_get(client, block) -> None:
    pts = [xy(150, -5), xy(200, 50), xy(50, -5)]
    got = route(client, block["name"], pts, cost="distance")
    posted = client.post(f"/networks/{block['name']}/route",
                         json={"points": [list(p) for p in pts], "cost": "distance"})
    assert posted.status_code == 200
    assert posted.json()["routes"][0]["distance"] == got["routes"][0]["distance"]
    assert len(posted.json()["routes"][0]["legs"]) == 2


def test_osrm_url_shape_answers_like_osrm(client, block) -> None:
    (ax, ay), (bx, by) = xy(150, -5), xy(50, -5)
    r = client.get(f"/networks/{block['name']}/route/v1/driving/{ax},{ay};{bx},{by}",
                   params={"overview": "full", "steps": "true"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["code"] == "Ok" and isinstance(body["routes"][0]["geometry"], str)  # polyline
    native = route(client, block["name"], [(ax, ay), (bx, by)])
    assert body["routes"][0]["duration"] == native["routes"][0]["duration"]


@pytest.mark.parametrize(("path", "status", "code", "needle"), [
    ("/networks/nope-nope/route?points=1.5,42.5;1.6,42.5", 404, "NotFound", "nope-nope"),
    ("/networks/{n}/route?points=1.5,42.5;abc", 400, "InvalidQuery", "point 2 "),
    ("/networks/{n}/route?points=1.5,42.5", 400, "InvalidOptions", "two points"),
    ("/networks/{n}/route?points=1.5,42.5;1.5,95", 422, "InvalidValue", "point 2 "),
    ("/networks/{n}/route?points=1.5,42.5;1.51,42.5&cost=fast", 400, "InvalidQuery", "cost"),
    ("/networks/{n}/route?points=1.5,42.5;1.5,42.6", 422, "NoSegment", "point 2 "),
])
def test_errors(client, block, path, status, code, needle) -> None:
    r = client.get(path.format(n=block["name"]))
    assert r.status_code == status, r.text
    assert r.json()["code"] == code and needle in r.json()["message"]


def test_snap_radius_is_configurable_per_request(client, block) -> None:
    q = ";".join(f"{lon!r},{lat!r}" for lon, lat in [xy(50, -8), xy(150, -1)])
    far = client.get(f"/networks/{block['name']}/route", params={"points": q, "radius": 5})
    assert far.status_code == 422 and far.json()["message"].startswith("point 1 (")
    near = client.get(f"/networks/{block['name']}/route", params={"points": q, "radius": 9})
    assert near.status_code == 200


def test_avoided_road_classes_are_detoured(client, writer) -> None:
    """A short service lane and a long residential way between the same two junctions."""
    name = unique("avoid")
    net = synthetic.create_network(writer, name)
    synthetic.add_line(writer, net, [xy(0, 0), xy(100, 0)], road_class="service")
    synthetic.add_line(writer, net, [xy(0, 0), xy(0, 60), xy(100, 60), xy(100, 0)],
                       road_class="residential")
    synthetic.add_line(writer, net, [xy(-50, 0), xy(0, 0)], road_class="residential")
    synthetic.add_line(writer, net, [xy(100, 0), xy(150, 0)], road_class="residential")
    pts = [xy(-40, -2), xy(140, -2)]
    short = route(client, name, pts, cost="distance")
    detour = route(client, name, pts, cost="distance", avoid="service,track")
    assert short["routes"][0]["distance"] == pytest.approx(180, abs=0.5)
    assert detour["routes"][0]["distance"] == pytest.approx(300, abs=0.5)
    classes = {s["road_class"] for leg in detour["routes"][0]["legs"] for s in leg["steps"]
               if "road_class" in s}
    assert classes == {"residential"}


def test_snaps_past_a_dense_other_network(client, writer) -> None:
    """Twenty segments of another network lie nearer than ours: snapping still finds ours."""
    other = synthetic.create_network(writer, unique("crowd"))
    for k in range(20):
        synthetic.add_line(writer, other, [xy(2000 + k, 0), xy(2000 + k, 10)])
    name = unique("lonely")
    ours = synthetic.create_network(writer, name)
    seg = synthetic.add_line(writer, ours, [xy(1950, -30), xy(2050, -30)])
    body = route(client, name, [xy(2005, 5), xy(2015, 5)], cost="distance")
    assert body["waypoints"][0]["segment_id"] == seg
    assert body["waypoints"][0]["distance"] == pytest.approx(35, abs=0.1)
    assert body["routes"][0]["distance"] == pytest.approx(10, abs=0.1)


def test_too_many_points_is_400(client, block) -> None:
    q = ";".join(f"{xy(i, 0)[0]},{LAT0}" for i in range(101))
    r = client.get(f"/networks/{block['name']}/route", params={"points": q})
    assert r.status_code == 400 and r.json()["code"] == "TooBig"


def _points(*points: tuple[float, float]) -> dict[str, str]:
    return {"points": ";".join(f"{lon!r},{lat!r}" for lon, lat in points)}


@pytest.fixture(scope="module")
def islands(writer) -> str:
    """Three pieces: A, 2 segments along y=0 (250 m); B, 3 segments along y=50 (1.5 km)
    joined by a motorway (x=1500, 350 m) to D, one segment along y=400 (250 m); and C, one
    one-way (eastbound) segment along y=200 (100 m)."""
    name = unique("islands")
    net = synthetic.create_network(writer, name)
    for coords in ([xy(0, 0), xy(100, 0)], [xy(100, 0), xy(250, 0)],
                   [xy(0, 50), xy(100, 50)], [xy(100, 50), xy(200, 50)],
                   [xy(200, 50), xy(1500, 50)]):
        synthetic.add_line(writer, net, coords)
    synthetic.add_line(writer, net, [xy(0, 200), xy(100, 200)], oneway="forward")
    synthetic.add_line(writer, net, [xy(1500, 50), xy(1500, 400)], road_class="motorway")
    synthetic.add_line(writer, net, [xy(1500, 400), xy(1750, 400)])
    return name


def test_points_on_different_pieces_are_named_with_the_pieces(client, islands) -> None:
    """The message counts points from 1, as the web map numbers them, and says which piece
    each point is on and how big: the user sees a gap to bridge, not a riddle."""
    r = client.get(f"/networks/{islands}/route", params=_points(xy(10, 1), xy(10, 49)))
    assert r.status_code == 422 and r.json()["code"] == "NoRoute"
    assert r.json()["message"] == (
        "no route from point 1 to point 2: point 1 is on a piece of the network of 2 segments "
        "(250 m) and point 2 on another of 5 segments (2.1 km): no road joins them")
    # Three points: the first two are joined, the third is not; the leg that fails is named.
    r = client.get(f"/networks/{islands}/route",
                   params=_points(xy(10, 1), xy(200, 1), xy(1600, 401)))
    assert r.json()["message"].startswith(
        "no route from point 2 to point 3: point 2 is on a piece of the network of 2 segments "
        "(250 m) and point 3 on another of 5 segments (2.1 km)")
    # Avoiding motorways cuts B from D: the pieces are counted without the avoided roads.
    r = client.get(f"/networks/{islands}/route",
                   params={**_points(xy(10, 49), xy(1600, 401)), "avoid": "motorway"})
    assert r.json()["message"] == (
        "no route from point 1 to point 2: point 1 is on a piece of the network of 3 segments "
        "(1.5 km) and point 2 on another of 1 segment (250 m) once roads of the classes "
        "not driven (motorway) are left out: no road joins them")
    # OSRM's URLs keep OSRM's code and status, with the same words.
    (ax, ay), (bx, by) = xy(10, 1), xy(10, 49)
    osrm = client.get(f"/networks/{islands}/route/v1/driving/{ax},{ay};{bx},{by}")
    assert osrm.status_code == 400 and osrm.json()["code"] == "NoRoute"
    assert osrm.json()["message"].startswith("no route from point 1 to point 2: point 1 is on")


def test_one_piece_kept_apart_by_one_way_says_so(client, islands) -> None:
    r = client.get(f"/networks/{islands}/route", params=_points(xy(80, 199), xy(20, 199)))
    assert r.status_code == 422 and r.json()["code"] == "NoRoute"
    assert r.json()["message"] == (
        "no route from point 1 to point 2: both are on one piece of the network (1 segment "
        "(100 m)), but its one-way roads (or the bearings and approaches asked for) lead no way "
        "from point 1 to point 2")
