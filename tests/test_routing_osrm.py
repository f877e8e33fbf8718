"""OSRM's route options, one by one, on synthetic networks with known answers; and OSRM's error
codes and statuses on the OSRM-shaped URLs."""

from __future__ import annotations

import itertools
import math

import polyline
import psycopg
import pytest

from app.routing.trace import VERTEX_BASE
from testkit import synthetic
from tests.osrm_schema import check
from tests.routing_support import dsn, route, town, unique, xy


@pytest.fixture(scope="module")
def writer(database_url: str):
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        yield conn


@pytest.fixture(scope="module")
def town_net(writer) -> dict:
    return town(writer, unique("town"))


@pytest.fixture(scope="module")
def street(writer) -> dict:
    """A two-way street (0,0)->(100,0)->(400,0) (two segments) with a two-way ring at its east
    end (centre (450,0), radius 50), Cross Road crossing it at x=100 and turning east at
    (100,100) under the same name, and a separate 4 km wiggly lane at y=1000."""
    name = unique("street")
    net = synthetic.create_network(writer, name)
    add = synthetic.add_line
    ring = [xy(450 + 50 * math.cos(math.radians(a)), 50 * math.sin(math.radians(a)))
            for a in range(180, 540, 30)]
    seg = {
        "street": add(writer, net, [xy(0, 0), xy(100, 0)], name="Long Street"),
        "street2": add(writer, net, [xy(100, 0), xy(400, 0)], name="Long Street"),
        "ring": add(writer, net, [xy(400, 0), *ring[1:], xy(400, 0)], name="Ring"),
        "cross": add(writer, net, [xy(100, -100), xy(100, 0)], name="Cross Road"),
        "cross2": add(writer, net, [xy(100, 0), xy(100, 100)], name="Cross Road"),
        "cross3": add(writer, net, [xy(100, 100), xy(200, 100)], name="Cross Road"),
        "wiggle": add(writer, net, [xy(k * 5, 1000 + (k % 2) * 0.3) for k in range(801)],
                      name="Wiggle Lane"),
    }
    return {"name": name, "seg": seg}


def osrm(client, name: str, pts, **params):
    coords = ";".join(f"{x!r},{y!r}" for x, y in pts)
    return client.get(f"/networks/{name}/route/v1/driving/{coords}", params=params)


def ok(resp) -> dict:
    assert resp.status_code == 200, resp.text
    return check(resp.json(), "route")  # OSRM's documented route response


# -- geometries and overview --------------------------------------------------------------
def test_polyline6_and_geojson_are_the_same_line(client, town_net) -> None:
    pts = [xy(20, -4), xy(405, 450)]
    gj = ok(osrm(client, town_net["name"], pts, geometries="geojson", overview="full"))
    p6 = ok(osrm(client, town_net["name"], pts, geometries="polyline6", overview="full"))
    line = gj["routes"][0]["geometry"]["coordinates"]
    decoded = polyline.decode(p6["routes"][0]["geometry"], 6)
    assert len(decoded) == len(line)
    for (lat, lon), (x, y) in zip(decoded, line, strict=True):
        assert (lat, lon) == pytest.approx((y, x), abs=1e-6)


def test_overview_simplified_thins_a_wiggly_road(client, street) -> None:
    pts = [xy(2, 1003), xy(3998, 1003)]
    full = ok(osrm(client, street["name"], pts, geometries="geojson", overview="full"))
    simple = ok(osrm(client, street["name"], pts, geometries="geojson"))  # OSRM's default
    a = full["routes"][0]["geometry"]["coordinates"]
    b = simple["routes"][0]["geometry"]["coordinates"]
    assert len(a) > 700 and len(b) == 2  # 30 cm wiggles vanish at the zoom showing 4 km
    assert b[0] == a[0] and b[-1] == a[-1]
    none = ok(osrm(client, street["name"], pts, overview="false"))
    assert "geometry" not in none["routes"][0]
    assert none["routes"][0]["distance"] == full["routes"][0]["distance"]


# -- steps -------------------------------------------------------------------------------
def test_steps_only_when_asked(client, town_net) -> None:
    pts = [xy(20, -4), xy(405, 450)]
    assert ok(osrm(client, town_net["name"], pts))["routes"][0]["legs"][0]["steps"] == []
    assert route(client, town_net["name"], pts, steps="false")["routes"][0]["legs"][0][
        "steps"] == []
    assert route(client, town_net["name"], pts)["routes"][0]["legs"][0]["steps"]  # ours: on


def test_unnamed_roads_straight_on_are_continue_not_new_name(client, writer) -> None:
    """Straight from one unnamed road onto another (class and lanes change, so a new step):
    ``continue``, since OSRM's ``new name`` announces a road name and there is none; a turn
    between them stays a ``turn``, and a name after them is a ``new name`` again."""
    name = unique("unnamed")
    net = synthetic.create_network(writer, name)
    synthetic.add_line(writer, net, [xy(0, 0), xy(200, 0)], road_class="service")
    synthetic.add_line(writer, net, [xy(200, 0), xy(400, 0)], road_class="tertiary",
                       lanes_forward=2)
    synthetic.add_line(writer, net, [xy(400, 0), xy(400, 200)], road_class="tertiary")
    synthetic.add_line(writer, net, [xy(400, 200), xy(400, 400)], name="Named Road")
    steps = route(client, name, [xy(10, 0), xy(400, 390)])["routes"][0]["legs"][0]["steps"]
    assert [(s["maneuver"]["type"], s["maneuver"].get("modifier")) for s in steps[:-1]] == [
        ("depart", None), ("continue", "straight"), ("turn", "left"), ("new name", "straight")]


def test_step_fields(client, town_net) -> None:
    body = ok(osrm(client, town_net["name"], [xy(20, -4), xy(405, 450)], steps="true",
                   geometries="geojson"))
    steps = body["routes"][0]["legs"][0]["steps"]
    assert [s["maneuver"]["type"] for s in steps] == [
        "depart", "new name", "turn", "roundabout", "exit roundabout", "arrive"]
    depart, new_name, turn, roundabout, leave, arrive = steps
    assert depart["maneuver"]["bearing_before"] == 0 and depart["maneuver"]["bearing_after"] == 90
    assert new_name["maneuver"]["modifier"] == "straight" and new_name["name"] == "High Street"
    assert new_name["maneuver"]["location"] == pytest.approx(list(xy(200, 0)), abs=1e-9)
    assert turn["maneuver"]["modifier"] == "left"
    assert (turn["maneuver"]["bearing_before"], turn["maneuver"]["bearing_after"]) == (90, 0)
    assert roundabout["maneuver"]["exit"] == 2 and roundabout["name"] == "North Road"
    assert leave["maneuver"]["exit"] == 2 and leave["name"] == "North Road"
    assert arrive["maneuver"]["modifier"] == "right" and arrive["name"] == "North Road"
    for s in steps:
        assert s["mode"] == "driving" and s["driving_side"] == "right"
        assert s["weight"] == pytest.approx(s["duration"])
        assert s["intersections"][0]["location"] == s["maneuver"]["location"]
    assert sum(s["distance"] for s in steps) == pytest.approx(body["routes"][0]["distance"])
    # The turn onto Church Lane: three roads meet at (400,0); we came from the west (bearing
    # 270 pointing back) and leave north (0).
    at = turn["intersections"][0]
    assert at["bearings"] == [0, 270] and at["entry"] == [True, True]
    assert at["bearings"][at["in"]] == 270 and at["bearings"][at["out"]] == 0
    # On the roundabout, each node with a road out is listed, one-way ring arcs not enterable.
    ring = roundabout["intersections"]
    assert len(ring) == 2  # the entry and the node at East Road
    assert len(ring[1]["bearings"]) == 3 and 90 in ring[1]["bearings"]
    assert ring[1]["entry"].count(False) == 1  # the ring arc behind us is one-way


def test_maneuver_types_follow_the_road_name(client, street) -> None:
    """Straight on the same road: one step; turning onto another road: ``turn``; turning
    while the road keeps its name: ``continue`` (OSRM's "Turn right to stay on ...")."""
    def maneuvers(a, b):
        body = ok(osrm(client, street["name"], [a, b], steps="true"))
        return [(s["maneuver"]["type"], s["maneuver"].get("modifier"))
                for s in body["routes"][0]["legs"][0]["steps"][1:-1]]

    assert maneuvers(xy(100, -80), xy(100, 80)) == []  # Cross Road through the junction
    assert maneuvers(xy(100, -80), xy(300, 2)) == [("turn", "right")]
    assert maneuvers(xy(100, -80), xy(190, 102)) == [("continue", "right")]


# -- annotations -------------------------------------------------------------------------
def test_annotations_per_coordinate_pair(client, town_net, writer) -> None:
    pts = [xy(20, -4), xy(300, 4), xy(405, 450)]
    body = ok(osrm(client, town_net["name"], pts, annotations="true", overview="full",
                   geometries="geojson"))
    r = body["routes"][0]
    line = r["geometry"]["coordinates"]
    pairs = 0
    nodes = {row[0] for row in writer.execute("SELECT id FROM road_nodes WHERE network_id = %s",
                                              (town_net["net"],))}
    for leg in r["legs"]:
        a = leg["annotation"]
        n = len(a["distance"])
        assert len(a["duration"]) == len(a["speed"]) == len(a["weight"]) == n
        assert len(a["datasources"]) == n and len(a["nodes"]) == n + 1
        assert sum(a["distance"]) == pytest.approx(leg["distance"])
        assert sum(a["duration"]) == pytest.approx(leg["duration"])
        assert a["weight"] == a["duration"]
        assert all(s == pytest.approx(d / t, abs=0.05)
                   for s, d, t in zip(a["speed"], a["distance"], a["duration"], strict=True))
        assert a["metadata"] == {"datasource_names": ["ugvmap"]}
        segs = {s["id"] for s in leg["segments"]}
        for node in a["nodes"]:  # network nodes, or vertices of the segments driven
            assert node in nodes or -node // VERTEX_BASE in segs
        pairs += n
    assert pairs == len(line) - 1  # one entry per consecutive pair of the full overview
    # Each pair's distance is the ground distance between its coordinates.
    dists = [d for leg in r["legs"] for d in leg["annotation"]["distance"]]
    for (p, q), d in zip(itertools.pairwise(line), dists, strict=True):
        dx = (q[0] - p[0]) * 111_320 * math.cos(math.radians(42.5))
        assert math.hypot(dx, (q[1] - p[1]) * 111_132) == pytest.approx(d, rel=0.01, abs=0.05)


def test_annotations_subset_and_off(client, town_net) -> None:
    pts = [xy(20, -4), xy(300, 4)]
    leg = ok(osrm(client, town_net["name"], pts, annotations="distance,speed"))["routes"][0][
        "legs"][0]
    assert set(leg["annotation"]) == {"distance", "speed"}
    assert "annotation" not in ok(osrm(client, town_net["name"], pts))["routes"][0]["legs"][0]


# -- alternatives ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def two_ways(writer) -> dict:
    """A straight 1000 m road and a 1112 m bow north of it (two segments: the graph keeps one
    arc per pair of junctions) between the same junctions."""
    name = unique("twoways")
    net = synthetic.create_network(writer, name)
    add = synthetic.add_line
    seg = {
        "west": add(writer, net, [xy(-100, 0), xy(0, 0)]),
        "south": add(writer, net, [xy(0, 0), xy(500, 0), xy(1000, 0)]),
        "north": add(writer, net, [xy(0, 0), xy(100, 120), xy(500, 120)]),
        "north2": add(writer, net, [xy(500, 120), xy(900, 120), xy(1000, 0)]),
        "east": add(writer, net, [xy(1000, 0), xy(1100, 0)]),
    }
    return {"name": name, "seg": seg}


def test_alternatives_are_real_and_different(client, two_ways) -> None:
    pts = [xy(-90, 2), xy(1090, 2)]
    one = ok(osrm(client, two_ways["name"], pts))
    assert len(one["routes"]) == 1
    body = ok(osrm(client, two_ways["name"], pts, alternatives="true"))
    best, alt = body["routes"]
    seg = two_ways["seg"]
    assert [s["id"] for s in best["legs"][0]["segments"]] == [seg["west"], seg["south"],
                                                               seg["east"]]
    assert [s["id"] for s in alt["legs"][0]["segments"]] == [seg["west"], seg["north"],
                                                              seg["north2"], seg["east"]]
    assert best["distance"] == pytest.approx(1180, abs=1)
    assert best["weight"] < alt["weight"] <= 1.25 * best["weight"]
    many = ok(osrm(client, two_ways["name"], pts, alternatives="3"))
    assert len(many["routes"]) == 2  # no third road that is clearly different


def test_alternatives_beyond_the_limit_are_too_big(client, two_ways) -> None:
    r = osrm(client, two_ways["name"], [xy(-90, 2), xy(1090, 2)], alternatives="9")
    assert r.status_code == 400 and r.json()["code"] == "TooBig"


# -- exclude -----------------------------------------------------------------------------
def test_exclude_motorway_detours_and_toll_is_unknown(client, writer) -> None:
    name = unique("exclude")
    net = synthetic.create_network(writer, name)
    synthetic.add_line(writer, net, [xy(0, 0), xy(1000, 0)], road_class="motorway")
    synthetic.add_line(writer, net, [xy(0, 0), xy(0, 300), xy(1000, 300), xy(1000, 0)],
                       road_class="residential")
    pts = [xy(0, -1), xy(1000, -1)]
    assert ok(osrm(client, name, pts))["routes"][0]["distance"] == pytest.approx(1000, abs=1)
    detour = ok(osrm(client, name, pts, exclude="motorway"))
    assert detour["routes"][0]["distance"] == pytest.approx(1600, abs=1)
    r = osrm(client, name, pts, exclude="toll")
    assert r.status_code == 400 and r.json()["code"] == "InvalidValue"
    assert "toll" in r.json()["message"] and "motorway" in r.json()["message"]
    r = client.get(f"/networks/{name}/route",
                   params={"points": f"{pts[0][0]},{pts[0][1]};{pts[1][0]},{pts[1][1]}",
                           "exclude": "toll"})
    assert r.status_code == 422 and r.json()["code"] == "InvalidValue"


# -- radiuses, bearings, approaches, continue_straight -----------------------------------
def test_radiuses_per_point(client, street) -> None:
    pts = [xy(50, -8), xy(300, -1)]  # point 1 is 8 m from the street
    r = osrm(client, street["name"], pts, radiuses="5;")
    assert r.status_code == 400 and r.json()["code"] == "NoSegment"
    assert r.json()["message"].startswith("point 1 (")
    ok(osrm(client, street["name"], pts, radiuses="10;unlimited"))
    r = osrm(client, street["name"], pts, radiuses="10")
    assert r.status_code == 400 and r.json()["code"] == "InvalidOptions"
    r = osrm(client, street["name"], pts, radiuses="10;20000")
    assert r.status_code == 400 and r.json()["code"] == "InvalidValue"


def test_bearing_picks_the_road_going_that_way(client, street) -> None:
    # 3 m north of the street, 5 m east of Cross Road: the street is nearer.
    pts = [xy(105, 3), xy(100, 90)]
    plain = ok(osrm(client, street["name"], pts))
    assert plain["waypoints"][0]["segment_id"] == street["seg"]["street2"]
    north = ok(osrm(client, street["name"], pts, bearings="0,20;"))
    assert north["waypoints"][0]["segment_id"] == street["seg"]["cross2"]
    r = osrm(client, street["name"], pts, bearings="0,200;")
    assert r.status_code == 400 and r.json()["code"] == "InvalidOptions"


def test_curb_approach_arrives_with_the_point_on_the_right(client, street) -> None:
    pts = [xy(50, -5), xy(300, 5)]  # the end lies north of the street: the left going east
    plain = ok(osrm(client, street["name"], pts))
    assert plain["routes"][0]["distance"] == pytest.approx(250, abs=1)
    curb = ok(osrm(client, street["name"], pts, approaches="curb;curb", steps="true"))
    # On to the next junction (400,0), back westwards: 50 + 300 + 100 m (the graph allows
    # turning back at a junction).
    assert curb["routes"][0]["distance"] == pytest.approx(450, abs=1)
    assert curb["routes"][0]["legs"][0]["segments"][-1]["forward"] is False
    arrive = curb["routes"][0]["legs"][0]["steps"][-1]
    assert arrive["maneuver"]["modifier"] == "right"
    r = osrm(client, street["name"], pts, approaches="curb;kerb")
    assert r.status_code == 400 and r.json()["code"] == "InvalidQuery"


def test_continue_straight_forbids_u_turns_at_waypoints(client, street) -> None:
    pts = [xy(150, -2), xy(300, -2), xy(200, -2)]
    turning = ok(osrm(client, street["name"], pts))
    assert turning["routes"][0]["distance"] == pytest.approx(250, abs=1)
    straight = ok(osrm(client, street["name"], pts, continue_straight="true"))
    legs = straight["routes"][0]["legs"]
    assert legs[0]["distance"] == pytest.approx(150, abs=1)
    # Eastwards out of the waypoint to the junction at (400,0) and back: 100 + 200 m.
    assert legs[1]["distance"] == pytest.approx(300, abs=1)
    assert legs[1]["segments"][0]["forward"] is True
    r = osrm(client, street["name"], pts, continue_straight="maybe")
    assert r.status_code == 400 and r.json()["code"] == "InvalidQuery"


# -- waypoints and hints -----------------------------------------------------------------
def test_hints_are_given_and_taken(client, street) -> None:
    pts = [xy(50, -5), xy(300, 5)]
    body = ok(osrm(client, street["name"], pts))
    hints = [w["hint"] for w in body["waypoints"]]
    assert all(hints)
    again = ok(osrm(client, street["name"], pts, hints=";".join(hints)))
    assert again["routes"][0]["distance"] == body["routes"][0]["distance"]
    ok(osrm(client, street["name"], pts, hints=";"))  # what LRM sends the first time
    assert "hint" not in ok(osrm(client, street["name"], pts, generate_hints="false"))[
        "waypoints"][0]
    assert "waypoints" not in ok(osrm(client, street["name"], pts, skip_waypoints="true"))
    r = osrm(client, street["name"], pts, hints="a;b;c")
    assert r.status_code == 400 and r.json()["code"] == "InvalidOptions"
    r = osrm(client, street["name"], pts, hints="a b;c")
    assert r.status_code == 400 and r.json()["code"] == "InvalidQuery"


def test_coordinates_as_polyline_and_json_suffix(client, street) -> None:
    pts = [xy(50, -5), xy(300, 5)]
    plain = ok(osrm(client, street["name"], pts))
    encoded = polyline.encode([(lat, lon) for lon, lat in pts], 6)
    r = client.get(f"/networks/{street['name']}/route/v1/driving/polyline6({encoded})")
    assert ok(r)["routes"][0]["distance"] == pytest.approx(plain["routes"][0]["distance"],
                                                           abs=0.2)  # 1e-6 degrees
    coords = ";".join(f"{x},{y}" for x, y in pts)
    ok(client.get(f"/networks/{street['name']}/route/v1/driving/{coords}.json"))


# -- errors ------------------------------------------------------------------------------
@pytest.mark.parametrize(("suffix", "code"), [
    ("route/v1/driving/{c}?steps=yes", "InvalidQuery"),
    ("route/v1/driving/{c}?overview=banana", "InvalidQuery"),
    ("route/v1/driving/{c}?geometries=wkt", "InvalidQuery"),
    ("route/v1/driving/{c}?annotations=nodes,colour", "InvalidQuery"),
    ("route/v1/driving/{c}?tidy=true", "InvalidQuery"),
    ("route/v1/driving/{c}?steps=true&steps=false", "InvalidQuery"),
    ("route/v1/driving/{c}?waypoints=0;1", "NotImplemented"),
    ("route/v1/driving/1.5,42.5", "InvalidOptions"),
    ("route/v1/driving/1.5,42.5;1.5,95", "InvalidValue"),
    ("route/v1/driving/1.5,42.5;1.5,nan", "InvalidQuery"),
    ("route/v1/driving/1.5,42.5;1.5,42.6", "NoSegment"),
    ("route/v2/driving/{c}", "InvalidVersion"),
    ("tile/v1/driving/{c}", "InvalidService"),
    ("route/v1/driving", "InvalidUrl"),
    ("route/v1/dri%20ving/{c}", "InvalidUrl"),
])
def test_osrm_errors_are_400_with_osrm_codes(client, street, suffix, code) -> None:
    c = ";".join(f"{x},{y}" for x, y in [xy(50, -5), xy(300, 5)])
    r = client.get(f"/networks/{street['name']}/" + suffix.format(c=c))
    assert r.status_code == 400, r.text
    assert check(r.json(), "error")["code"] == code


def test_no_route_is_400_on_osrm_urls_and_422_on_ours(client, writer) -> None:
    name = unique("islands")
    net = synthetic.create_network(writer, name)
    synthetic.add_line(writer, net, [xy(0, 0), xy(100, 0)])
    synthetic.add_line(writer, net, [xy(0, 50), xy(100, 50)])
    pts = [xy(10, 1), xy(10, 49)]
    r = osrm(client, name, pts)
    assert r.status_code == 400 and r.json()["code"] == "NoRoute"
    q = ";".join(f"{x},{y}" for x, y in pts)
    r = client.get(f"/networks/{name}/route", params={"points": q})
    assert r.status_code == 422 and r.json()["code"] == "NoRoute"
