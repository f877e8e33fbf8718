"""A re-survey of a network as a change set, through the real command line, app and PostGIS:
proposed (``ingest network FILE --update``), listed, accepted in bulk and one by one,
rejected, reverted as a whole; a person's edit never changed by a bulk accept; routing sees
a new road only once accepted; two updates at once and a survey of another place refused."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner
from shapely import wkt
from sqlalchemy import text

from app.db.session import get_engine
from cli.main import main
from testkit.network_helpers import bearer, grid_network

STEP = 0.001  # the grid's block, in degrees
EAST_4M = 4.0 / (111_320 * np.cos(np.radians(50.0)))  # 4 m east, in degrees of longitude


def rows(sql: str, **values: object) -> list[Any]:
    with get_engine().connect() as conn:
        return list(conn.execute(text(sql), values).all())


def redrawn(coords: list[tuple[float, float]], seed: int) -> list[list[float]]:
    """A line digitised again: vertices every ~5 m, each off by ~0.3 m."""
    rng = np.random.default_rng(seed)
    a, b = np.array(coords[0]), np.array(coords[-1])
    t = np.linspace(0, 1, 30)[:, None]
    points = a + t * (b - a) + rng.normal(0, 0.3 / 111_000, (30, 2))
    return points.round(9).tolist()


def survey(path: Path, *, offset: tuple[float, float] = (0.0, 0.0)) -> Path:
    """The grid surveyed again: Column 2 moved 4 m east, Row 0's west block gone, and a new
    road north from the middle of Row 2's west block."""
    dx, dy = offset
    lines = []
    for i in range(3):
        west = 10.0 + STEP if i == 0 else 10.0  # Row 0 now starts at the middle column
        lines.append([(west + dx, 50.0 + i * STEP + dy), (10.0 + 2 * STEP + dx,
                                                            50.0 + i * STEP + dy)])
        shift = EAST_4M if i == 2 else 0.0
        lines.append([(10.0 + i * STEP + shift + dx, 50.0 + dy),
                      (10.0 + i * STEP + shift + dx, 50.0 + 2 * STEP + dy)])
    lines.append([(10.0005 + dx, 50.002 + dy), (10.0005 + dx, 50.0027 + dy)])
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"road_class": "residential"},
         "geometry": {"type": "LineString", "coordinates": redrawn(line, seed)}}
        for seed, line in enumerate(lines)]}))
    return path


def segment_at(network_id: int, lon: float, lat: float) -> int:
    return rows("SELECT id FROM road_segments WHERE network_id = :n ORDER BY "
                "geom <-> ST_SetSRID(ST_MakePoint(:x, :y), 4326) LIMIT 1",
                n=network_id, x=lon, y=lat)[0].id


def update(path: Path, name: str) -> int:
    result = CliRunner().invoke(main, ["ingest", "network", str(path), "--network", name,
                                       "--update"])
    assert result.exit_code == 0, result.output
    return int(result.output.split()[2])


def route_to_new_road(client, name: str) -> Any:
    return client.get(f"/networks/{name}/route",
                      params={"points": "10.0,50.0;10.0005,50.0026", "radius": "20"})


@pytest.fixture()
def grid(database_url: str) -> dict[str, Any]:
    summary = grid_network()
    n = summary.network_id
    return {"name": summary.network, "id": n,
            "moved": [segment_at(n, 10.002, 50.0005), segment_at(n, 10.002, 50.0015)],
            "gone": segment_at(n, 10.0005, 50.0)}


def test_a_resurvey_proposes_and_accepting_it_keeps_a_persons_edit(
        client, grid: dict[str, Any], tmp_path: Path) -> None:
    name, editor = grid["name"], bearer("editor")
    edited, plain = grid["moved"]
    patched = client.patch(f"/collections/{name}-segments/items/{edited}",
                           json={"name": "Mill Lane"}, headers=editor)
    assert patched.status_code == 200, patched.text
    before = rows("SELECT id, version, ST_AsText(geom) AS g FROM road_segments "
                  "WHERE network_id = :n ORDER BY id", n=grid["id"])
    set_id = update(survey(tmp_path / "survey.geojson"), name)
    # Proposing changes nothing in the network, and routing does not see the new road.
    assert rows("SELECT id, version, ST_AsText(geom) AS g FROM road_segments "
                "WHERE network_id = :n ORDER BY id", n=grid["id"]) == before
    unrouted = route_to_new_road(client, name)
    listed = client.get(f"/networks/{name}/changes").json()
    assert [(s["id"], s["status"], s["counts"]) for s in listed] == [
        (set_id, "open", {"unchanged": 9, "moved": 2, "new": 1, "missing": 1, "unseen": 0})]
    shown = client.get(f"/change-sets/{set_id}").json()
    kinds = {(f["properties"]["kind"], f["properties"]["segment_id"],
              f["properties"]["edited"]) for f in shown["features"]}
    assert kinds == {("moved", edited, True), ("moved", plain, False),
                     ("missing", grid["gone"], False), ("new", None, False)}
    by_kind = {f["properties"]["segment_id"] or "new": f["id"] for f in shown["features"]}

    assert client.post(f"/change-sets/{set_id}/accept",
                       json={"all": True}).status_code == 401
    done = client.post(f"/change-sets/{set_id}/accept", json={"all": True},
                       headers=editor).json()
    assert done == {"accepted": 3, "edited": 1, "stale": 0, "refused": 0}
    kept = rows("SELECT name, version, ST_AsText(geom) AS g FROM road_segments WHERE id = :s",
                s=edited)[0]
    assert kept.name == "Mill Lane" and kept.version == 2  # the person's edit, untouched
    assert not rows("SELECT 1 FROM road_segments WHERE id = :s", s=grid["gone"])
    history = client.get(f"/collections/{name}-segments/items/{plain}/history").json()["edits"]
    assert history[-1]["action"] == "resurvey" and history[-1]["new"]["change_set"] == set_id
    assert history[-1]["version_to"] == 2
    moved = rows("SELECT ST_X(ST_LineInterpolatePoint(geom, 0.5)) AS x FROM road_segments "
                 "WHERE id = :s", s=plain)[0].x
    assert moved - 10.002 == pytest.approx(EAST_4M, abs=EAST_4M / 4)
    routed = route_to_new_road(client, name)
    assert routed.status_code == 200, routed.text
    # Before: no road within 20 m of the new road's end; after: the route ends on it.
    assert unrouted.status_code == 422 and unrouted.json()["code"] == "NoSegment"
    assert routed.json()["routes"][0]["distance"] > 300
    assert CliRunner().invoke(main, ["network", "validate", name]).exit_code == 0

    one = client.post(f"/change-sets/{set_id}/accept",
                      json={"changes": [by_kind[edited]]}, headers=editor).json()
    assert one["accepted"] == 1  # looked at alone, a person's segment may change too

    reverted = client.post(f"/change-sets/{set_id}/revert", headers=editor).json()
    assert reverted == {"reverted": 4, "gone": 0}
    after = [wkt.loads(r.g) for r in rows("SELECT ST_AsText(geom) AS g FROM road_segments "
                                          "WHERE network_id = :n", n=grid["id"])]
    assert len(after) == len(before)  # the split road merged back, the deleted one restored
    assert all(any(wkt.loads(b.g).equals(a) for a in after) for b in before)
    assert rows("SELECT name FROM road_segments WHERE id = :s", s=edited)[0].name == "Mill Lane"
    assert client.get(f"/networks/{name}/changes").json()[0]["status"] == "reverted"
    again = client.post(f"/change-sets/{set_id}/accept", json={"all": True},
                        headers=editor)
    assert again.status_code == 409
    assert CliRunner().invoke(main, ["network", "validate", name]).exit_code == 0
    listing = CliRunner().invoke(main, ["network", "changes", name])
    assert f"{set_id}\t" in listing.output and "reverted" in listing.output


def test_reject_by_kind_and_box_changes_nothing(client, grid: dict[str, Any],
                                                tmp_path: Path) -> None:
    name, editor = grid["name"], bearer("editor")
    set_id = update(survey(tmp_path / "survey.geojson"), name)
    url = f"/change-sets/{set_id}"
    box = [10.0, 49.9999, 10.0011, 50.0001]  # Row 0's west block only
    assert client.post(url + "/reject", json={"bbox": box, "kind": "missing"},
                       headers=editor).json() == {"rejected": 1}
    assert client.post(url + "/accept", json={"kind": "missing"},
                       headers=editor).json()["accepted"] == 0
    assert rows("SELECT 1 FROM road_segments WHERE id = :s", s=grid["gone"])
    assert client.post(url + "/reject", json={"kind": "sideways"},
                       headers=editor).status_code == 422
    assert client.post(url + "/reject", json={"all": True, "kind": "new"},
                       headers=editor).status_code == 422
    assert client.get(f"/change-sets/{set_id + 1000}").status_code == 404


def test_a_second_update_at_once_and_a_survey_elsewhere_are_refused(
        grid: dict[str, Any], tmp_path: Path) -> None:
    path = survey(tmp_path / "survey.geojson")
    with get_engine().connect() as conn:  # an update of the network holds its lock
        assert conn.execute(text("SELECT pg_try_advisory_xact_lock("
                                 "hashtext('ugvmap.resurvey'), :n)"), {"n": grid["id"]}).scalar()
        busy = CliRunner().invoke(main, ["ingest", "network", str(path), "--network",
                                         grid["name"], "--update"])
        conn.rollback()
    assert busy.exit_code == 1 and "another update of network" in busy.output
    far = survey(tmp_path / "far.geojson", offset=(1.0, 1.0))
    elsewhere = CliRunner().invoke(main, ["ingest", "network", str(far), "--network",
                                          grid["name"], "--update"])
    assert elsewhere.exit_code == 1 and "does not overlap network" in elsewhere.output
    assert not rows("SELECT 1 FROM change_sets c JOIN networks n ON n.id = c.network_id "
                    "WHERE n.name = :name", name=grid["name"])
    both = CliRunner().invoke(main, ["ingest", "network", str(path), "--network",
                                     grid["name"], "--update", "--replace"])
    assert both.exit_code == 1 and "exclude each other" in both.output
    bad = CliRunner().invoke(main, ["ingest", "network", str(path), "--network", grid["name"],
                                    "--update", "--tolerance", "match_m=-2"])
    assert bad.exit_code == 2 and "match_m must be a positive number" in bad.output


def test_a_new_road_joining_a_persons_road_waits_for_a_look(client, grid: dict[str, Any],
                                                           tmp_path: Path) -> None:
    name, editor = grid["name"], bearer("editor")
    joined = segment_at(grid["id"], 10.0005, 50.002)  # the new road joins its side
    assert client.patch(f"/collections/{name}-segments/items/{joined}",
                        json={"surface": "gravel"}, headers=editor).status_code == 200
    set_id = update(survey(tmp_path / "survey.geojson"), name)
    [new] = [f for f in client.get(f"/change-sets/{set_id}").json()["features"]
             if f["properties"]["kind"] == "new"]
    assert new["properties"]["edited"] and new["properties"]["detail"]["joins"][0] == joined
    done = client.post(f"/change-sets/{set_id}/accept", json={"kind": "new"},
                       headers=editor).json()
    assert done["accepted"] == 0 and done["edited"] == 1
    assert rows("SELECT version FROM road_segments WHERE id = :s", s=joined)[0].version == 2


def test_ingest_roads_update_from_the_same_imagery_changes_nothing(database_url: str,
                                                                    tmp_path: Path) -> None:
    """A layer extracted into a network, then the same layer extracted again with --update:
    every segment seen unchanged in the layer's coverage, nothing proposed; a network of
    another place is refused."""
    from tests.test_road_previews import write_scene

    write_scene(tmp_path / "scene.tif")
    runner = CliRunner()
    assert runner.invoke(main, ["ingest", "raster", str(tmp_path / "scene.tif"), "--layer",
                                "resurvey-scene"]).exit_code == 0
    first = runner.invoke(main, ["ingest", "roads", "--layer", "resurvey-scene", "--network",
                                 "resurvey-roads"])
    assert first.exit_code == 0, first.output
    segments = int(first.output.split()[2])
    again = runner.invoke(main, ["ingest", "roads", "--layer", "resurvey-scene", "--network",
                                 "resurvey-roads", "--update"])
    assert again.exit_code == 0, again.output
    assert f"{segments} unchanged, 0 moved, 0 new, 0 missing, 0 unseen" in again.output
    [listed] = rows("SELECT source, layer_version, ST_Area(coverage) > 0 AS covered "
                    "FROM change_sets c JOIN networks n ON n.id = c.network_id "
                    "WHERE n.name = 'resurvey-roads'")
    assert listed.source == "layer:resurvey-scene" and listed.layer_version == 1 \
        and listed.covered
    grid = grid_network()  # around 10 E, 50 N: far from the scene
    elsewhere = runner.invoke(main, ["ingest", "roads", "--layer", "resurvey-scene",
                                     "--network", grid.network, "--update"])
    assert elsewhere.exit_code == 1 and "does not overlap network" in elsewhere.output


def test_a_queued_update_with_a_bad_tolerance_is_refused_when_asked_for(client) -> None:
    admin = bearer("admin")
    for tolerances, said in (({"match_m": -1}, "match_m must be a positive number"),
                             ({"nearness": 3}, "unknown tolerance 'nearness'")):
        body = {"kind": "ingest-network", "params": {
            "file": "/x.geojson", "network": "n", "update": True, "tolerances": tolerances}}
        answer = client.post("/jobs", json=body, headers=admin)
        assert answer.status_code == 422 and said in answer.text, answer.text
