"""Vehicle profiles (issue 34): a road vehicle never drives footways, a sidewalk robot may.

A small OSM extract goes through the real importer (the CLI): a street that goes round three
sides of a block (1 km) and a footway straight across it (400 m). Every way is kept and the
import says who may drive which; the default profile (car), OSRM's ``driving`` and ``car``
URLs and the CLI go round the block, the ``sidewalk`` profile takes the footway, and an
unknown profile is refused in words that list the profiles.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from testkit.synthetic_osm import write_ways
from tests.routing_support import route, unique, xy

ROUND = 1000.0  # the street: (0,0) -> (0,300) -> (400,300) -> (400,0), metres
ACROSS = 400.0  # the footway: (0,0) -> (400,0)
A, D = xy(0, 0), xy(400, 0)


@pytest.fixture(scope="module")
def block(database_url: str, tmp_path_factory: pytest.TempPathFactory) -> dict:
    out = tmp_path_factory.mktemp("profiles") / "block.osm.pbf"
    street = {"highway": "residential", "name": "Ring Street"}
    write_ways(out, [
        (street, [A, xy(0, 300)]), (street, [xy(0, 300), xy(400, 300)]),
        (street, [xy(400, 300), D]),
        ({"highway": "footway"}, [A, xy(200, 0), D]),
        ({"highway": "steps"}, [xy(400, 300), xy(400, 340)]),
    ])
    name = unique("block")
    result = CliRunner().invoke(main, ["ingest", "network", str(out), "--network", name])
    assert result.exit_code == 0, result.output
    with session_scope() as s:
        classes = dict(s.execute(text(
            "SELECT road_class, count(*) FROM road_segments s JOIN networks n "
            "ON n.id = s.network_id WHERE n.name = :n GROUP BY road_class"), {"n": name}).all())
    return {"name": name, "output": result.output, "classes": classes}


def _classes_driven(client, name: str, body: dict) -> set[str]:
    ids = {s["id"] for leg in body["routes"][0]["legs"] for s in leg["segments"]}
    return {client.get(f"/collections/{name}-segments/items/{i}").json()["properties"]
            ["road_class"] for i in ids}


def test_import_keeps_every_way_and_says_who_may_drive_it(block) -> None:
    assert block["classes"] == {"residential": 3, "footway": 1, "steps": 1}
    assert block["output"].splitlines()[-1] == (
        "profiles: car may drive 3 of 5 segments (not 1 footway, 1 steps); "
        "sidewalk 4 (not 1 steps)")


def test_default_and_car_never_take_the_footway(client, block) -> None:
    name = block["name"]
    default = route(client, name, [A, D])
    assert default["routes"][0]["distance"] == pytest.approx(ROUND, abs=0.5)
    assert _classes_driven(client, name, default) == {"residential"}
    for alias in ("car", "driving"):
        ours = route(client, name, [A, D], profile=alias)
        assert ours["routes"][0]["distance"] == pytest.approx(ROUND, abs=0.5)
        (ax, ay), (dx, dy) = A, D
        osrm = client.get(f"/networks/{name}/route/v1/{alias}/{ax},{ay};{dx},{dy}")
        assert osrm.status_code == 200, osrm.text
        assert osrm.json()["routes"][0]["distance"] == pytest.approx(ROUND, abs=0.5)


def test_a_sidewalk_robot_takes_the_footway(client, block) -> None:
    name = block["name"]
    body = route(client, name, [A, D], profile="sidewalk")
    assert body["routes"][0]["distance"] == pytest.approx(ACROSS, abs=0.5)
    assert _classes_driven(client, name, body) == {"footway"}
    (ax, ay), (dx, dy) = A, D
    osrm = client.get(f"/networks/{name}/route/v1/sidewalk/{ax},{ay};{dx},{dy}")
    assert osrm.json()["routes"][0]["distance"] == pytest.approx(ACROSS, abs=0.5)
    posted = client.post(f"/networks/{name}/route", json={"points": [A, D], "profile": "robot"})
    assert posted.json()["routes"][0]["distance"] == pytest.approx(ACROSS, abs=0.5)
    assert client.get("/routing/profiles", params={"name": "car"}).status_code == 400
    listed = client.get("/routing/profiles").json()
    assert listed["default"] == "car"
    assert [(p["name"], p["aliases"], "footway" in p["never"]) for p in listed["profiles"]] == [
        ("car", ["driving"], True), ("sidewalk", ["robot"], False)]


def test_a_point_on_the_footway_alone_is_no_place_for_a_car(client, block) -> None:
    """Snapping sees only what the vehicle may drive: mid-footway is 300 m from the street."""
    mid = xy(200, 5)
    r = client.get(f"/networks/{block['name']}/route",
                   params={"points": f"{mid[0]},{mid[1]};{D[0]},{D[1]}"})
    assert r.status_code == 422 and r.json()["code"] == "NoSegment"
    assert r.json()["message"].endswith(
        "from any road: the nearest road is 200.0 m away; the footway 5.0 m away is not "
        "driven (the vehicle profile or avoid= leaves it out)"), r.json()["message"]
    assert route(client, block["name"], [mid, D], profile="sidewalk")["routes"][0][
        "distance"] == pytest.approx(200, abs=0.5)


def test_an_unknown_profile_is_refused_in_words(client, block) -> None:
    name = block["name"]
    (ax, ay), (dx, dy) = A, D
    ours = client.get(f"/networks/{name}/route", params={"points": f"{ax},{ay};{dx},{dy}",
                                                        "profile": "bike"})
    assert ours.status_code == 422 and ours.json()["code"] == "InvalidValue"
    assert ours.json()["message"] == ("profile 'bike' is unknown; the profiles are car (or "
                                      "driving), sidewalk (or robot)")
    osrm = client.get(f"/networks/{name}/route/v1/bike/{ax},{ay};{dx},{dy}")
    assert osrm.status_code == 400 and osrm.json()["code"] == "InvalidValue"
    # The other services and the isochrone take the vehicle too.
    assert client.get(f"/networks/{name}/nearest", params={
        "point": f"{ax},{ay}", "profile": "bike"}).status_code == 422
    assert client.get(f"/networks/{name}/isochrone", params={
        "point": f"{ax},{ay}", "seconds": "60", "profile": "bike"}).status_code == 422


def test_the_cli_honours_the_profile(block, tmp_path: Path) -> None:
    (ax, ay), (dx, dy) = A, D
    points = f"{ax!r},{ay!r};{dx!r},{dy!r}"
    runner = CliRunner()
    car = runner.invoke(main, ["route", block["name"], "--points", points])
    assert car.exit_code == 0, car.output
    assert car.output.splitlines()[-1].startswith("total: 1000.0 m")
    robot = runner.invoke(main, ["route", block["name"], "--points", points,
                                 "--profile", "sidewalk"])
    assert robot.output.splitlines()[-1].startswith("total: 400.0 m"), robot.output
