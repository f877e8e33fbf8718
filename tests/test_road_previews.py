"""Road previews and their acceptance: ``POST /layers/{slug}/previews`` queues the extraction
of a view, a real worker runs it (``ugvmap serve``'s own, or the task run here), and
``.../accept`` matches the preview's roads against the network there and applies what changed
to unreviewed extracted roads, keeping a person's."""

from __future__ import annotations

import os
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import Geod, Transformer
from rasterio.transform import from_origin
from sqlalchemy import text

from app.db.session import get_engine, session_scope
from cli.main import main
from ingest.queue import tasks
from ingest.raster.job import ingest_raster
from ingest.roads import RoadsInputError
from ingest.roads.layer import ingest_layer_roads
from ingest.roads.pipeline import ExtractParams
from ingest.roads.review import review_labels
from ingest.roads.synthetic import Scene, render
from testkit.network_helpers import bearer
from testkit.raster_synth import UTM33, utm_origin, write_tif
from testkit.server import running_server

RES = 0.5
SIZE = (300, 400)  # rows, columns: 150 x 200 m
# A cross with a T arm, in pixels (what tests/test_roads_ingest.py extracts).
ROADS = [[(20, 150), (380, 150)], [(200, 20), (200, 280)], [(60, 150), (60, 280)]]
CORNER = (15.31, 48.32)


def write_scene(path: Path, seed: int = 3) -> tuple[float, float, float, float]:
    """The scene as a UTM GeoTIFF; its lon/lat box, shrunk by a pixel (inside the image)."""
    rgb, _ = render(Scene(SIZE, roads=ROADS, seed=seed))
    east, north = utm_origin(*CORNER)
    transform = from_origin(round(east), round(north), RES, RES)
    write_tif(path, np.moveaxis(rgb, -1, 0), UTM33, transform)
    to_lonlat = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)
    lons, lats = to_lonlat.transform(*(transform @ np.array(
        [[1, 1, SIZE[1] - 1, SIZE[1] - 1], [1, SIZE[0] - 1, 1, SIZE[0] - 1]])))
    return min(lons), min(lats), max(lons), max(lats)


@pytest.fixture(scope="module")
def scene(module_database: str, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Layer ``teach`` (the scene) and network ``teach-net`` extracted from it zero-shot."""
    folder = tmp_path_factory.mktemp("teach")
    bbox = write_scene(folder / "scene.tif")
    ingest_raster([folder / "scene.tif"], "teach")
    with session_scope() as session:
        ingest_layer_roads(session, "teach", "teach-net", None, ExtractParams())
    return {"bbox": list(bbox), "tif": folder / "scene.tif", "folder": folder}


def scalar(sql: str, **values: object) -> object:
    with get_engine().connect() as conn:
        return conn.execute(text(sql), values).scalar()


def _reingest(scene: dict) -> None:
    """A new survey of the same place in the layer's place: its version goes up."""
    again = scene["folder"] / "resurvey.tif"
    write_scene(again, seed=4)
    ingest_raster([again], "teach", replace=True)


def test_preview_requests_need_an_editor_and_a_view_on_the_layer(client, scene) -> None:
    url, body = "/layers/teach/previews", {"bbox": scene["bbox"]}
    assert client.post(url, json=body).status_code == 401
    assert client.post(url, json=body, headers=bearer("viewer")).status_code == 403
    editor = bearer("editor")
    off = client.post(url, json={"bbox": [2.0, 41.0, 2.001, 41.001]}, headers=editor)
    assert off.status_code == 422 and "does not meet layer teach's imagery" in \
        off.json()["message"]
    x0, y0, _, _ = scene["bbox"]
    wide = client.post(url, json={"bbox": [x0, y0, x0 + 0.05, y0 + 0.03]}, headers=editor)
    assert wide.status_code == 422
    assert "a preview extracts at most 2048 x 2048 px: zoom in" in wide.json()["message"]
    for bad in ([1, 2, 3], [x0, y0, x0 - 1, y0 + 1], ["a", 1, 2, 3], [0, 89, 1, 90]):
        answer = client.post(url, json={"bbox": bad}, headers=editor)
        assert answer.status_code == 422 and "bbox" in answer.json()["errors"], bad
    assert client.post("/layers/nope/previews", json=body, headers=editor).status_code == 404
    assert scalar("SELECT count(*) FROM ingest_jobs WHERE kind = 'road-preview'") == 0


def test_serve_runs_a_preview_on_its_own_worker(module_database: str, scene) -> None:
    """``ugvmap serve`` starts a queue worker: the preview runs with no other command."""
    env = {"DATABASE_URL": module_database,
           "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"]}
    with running_server(env, queue_workers=1, timeout_s=120) as base, \
            httpx.Client(base_url=base) as http:
        asked = http.post("/layers/teach/previews", json={"bbox": scene["bbox"]},
                          headers=bearer("editor"))
        assert asked.status_code == 202, asked.text
        location = asked.headers["location"]
        deadline = time.monotonic() + 120
        while (preview := http.get(location).json())["status"] in ("queued", "running"):
            assert time.monotonic() < deadline, preview
            time.sleep(0.2)
    assert preview["status"] == "succeeded", preview
    # The worker that ran it stopped with the server (none is left to race later tests).
    worker = scalar("SELECT worker FROM ingest_jobs WHERE id = :id", id=preview["id"])
    with pytest.raises(ProcessLookupError):
        os.kill(int(str(worker).rsplit(":", 1)[1]), 0)
    result = preview["result"]
    assert result["classifier"] == "model" and result["labels"] == {"road": 0, "not_road": 0}
    assert preview["layer_version"] == scalar("SELECT version FROM layers WHERE slug = 'teach'")
    # The cross and its T arm: about 180 + 130 + 65 m of road, every line with a confidence.
    lengths = [Geod(ellps="WGS84").line_length(*zip(*f["geometry"]["coordinates"],
                                                    strict=True))
               for f in result["features"]]
    assert 300 < sum(lengths) < 450 and len(result["features"]) >= 3
    assert all(0 <= f["properties"]["confidence"] <= 1 for f in result["features"])
    assert all(f["properties"]["attrs"]["extracted_from"] == "teach"
               for f in result["features"])


def _preview(client, scene) -> int:
    """A finished preview of the whole scene, its task run here (the worker's own code)."""
    asked = client.post("/layers/teach/previews", json={"bbox": scene["bbox"]},
                        headers=bearer("editor"))
    assert asked.status_code == 202, asked.text
    preview_id = asked.json()["id"]
    assert client.get(f"/layers/teach/previews/{preview_id}").json()["status"] == "queued"
    tasks.run_job(preview_id)
    return preview_id


def _segments(network: str) -> dict[int, dict]:
    with get_engine().connect() as conn:
        return {r.id: dict(r._mapping) for r in conn.execute(text(
            "SELECT s.id, s.version, s.attrs, s.confidence FROM road_segments s "
            "JOIN networks n ON n.id = s.network_id WHERE n.name = :n"), {"n": network})}


def _history(network: str, fid: int) -> list[dict]:
    with get_engine().connect() as conn:
        return [dict(r._mapping) for r in conn.execute(text(
            "SELECT e.action, e.edited_by, e.old, e.new FROM segment_edits e "
            "JOIN networks n ON n.id = e.network_id WHERE n.name = :n AND e.segment_id = :s "
            "ORDER BY e.id"), {"n": network, "s": fid})]


def _as_an_older_extraction(scene: dict, missed: int, client) -> tuple[int, str]:
    """The network as an older extraction of the layer left it: segment ``missed`` never
    found, and a false road in an empty corner of the scene; the false road's id and the
    missed segment's line (EWKT). Both without history: the model's work nobody reviewed."""
    x0, y0, x1, y1 = scene["bbox"]

    def lonlat(col: float, row: float) -> list[float]:
        return [x0 + col / SIZE[1] * (x1 - x0), y1 - row / SIZE[0] * (y1 - y0)]

    made = client.post("/collections/teach-net-segments/items", json={
        "type": "Feature", "geometry": {"type": "LineString", "coordinates": [
            lonlat(300, 240), lonlat(380, 270)]},
        "properties": {"attrs": {"extracted_from": "teach"}}}, headers=bearer("editor"))
    assert made.status_code == 201, made.text
    false_road = int(made.json()["id"])
    with get_engine().begin() as conn:
        line = conn.execute(text("SELECT ST_AsEWKT(geom) FROM road_segments WHERE id = :s"),
                            {"s": missed}).scalar_one()
        ends = conn.execute(text("DELETE FROM road_segments WHERE id = :s "
                                 "RETURNING source_node, target_node"), {"s": missed}).one()
        conn.execute(text("DELETE FROM road_nodes n WHERE n.id = ANY(:ends) AND NOT EXISTS ("
                          "SELECT 1 FROM road_segments s WHERE n.id IN (s.source_node, "
                          "s.target_node))"), {"ends": list(ends)})
        conn.execute(text("DELETE FROM segment_edits WHERE segment_id = ANY(:s)"),
                     {"s": [missed, false_road]})
    return false_road, line


def test_accept_matches_the_preview_keeping_ids_and_a_persons_roads(client, scene) -> None:
    """Accepting matches the preview against the network (issue 36's matching): the roads it
    sees again keep their ids and history, a false road of an older extraction goes, a road
    it missed comes, a person's road stays; a second accept changes nothing; the accept is
    a change set, reverted in one step."""
    extracted = _segments("teach-net")
    assert len(extracted) >= 3
    edited, missed = min(extracted), max(extracted)
    patched = client.patch(f"/collections/teach-net-segments/items/{edited}",
                           json={"road_class": "service"}, headers=bearer("editor"))
    assert patched.status_code == 200, patched.text
    false_road, missed_line = _as_an_older_extraction(scene, missed, client)
    preview_id = _preview(client, scene)
    url = f"/layers/teach/previews/{preview_id}/accept"
    assert client.post(url, json={"network": "teach-net"},
                       headers=bearer("viewer")).status_code == 403
    assert client.post(url, json={"network": "nope"},
                       headers=bearer("editor")).status_code == 422
    before = _segments("teach-net")

    answer = client.post(url, json={"network": "teach-net"}, headers=bearer("editor"))
    assert answer.status_code == 200, answer.text
    counts = answer.json()
    after = _segments("teach-net")
    assert set(before) - set(after) == {false_road} and counts["removed"] == 1
    # Seen again: same ids, same versions, no new history (the person's road included).
    unchanged = set(before) - {false_road}
    assert {f: after[f]["version"] for f in unchanged} == \
        {f: before[f]["version"] for f in unchanged}
    assert after[edited]["attrs"] == before[edited]["attrs"]
    assert counts["kept"] >= len(unchanged) - counts["moved"] and counts["left"] == 0
    added = set(after) - set(before)
    assert len(added) == counts["added"] >= 1
    (gone,) = [e for e in _history("teach-net", false_road) if e["action"] == "accept"]
    assert gone["new"]["preview"] == preview_id
    assert gone["new"]["change_set"] == counts["change_set"]
    for fid in added:
        (created,) = _history("teach-net", fid)
        assert created["action"] == "accept" and created["new"]["preview"] == preview_id
        assert after[fid]["confidence"] is not None
        assert after[fid]["attrs"]["extracted_from"] == "teach"
    # The road found again lies along the missed one.
    assert scalar(
        "SELECT max(ST_Length(ST_Intersection(s.geom, ST_Buffer(CAST(:line AS geography), 3)"
        "::geometry)::geography)) / ST_Length(CAST(:line AS geography)) "
        "FROM road_segments s WHERE s.id = ANY(:added)", added=list(added), line=missed_line
    ) > 0.8

    validated = CliRunner().invoke(main, ["network", "validate", "teach-net"])
    assert validated.exit_code == 0 and "topology OK" in validated.output, validated.output
    # Accepted roads are the model's, not a review: only the person's edit is a label.
    with session_scope() as session:
        review = review_labels(session, "teach")
    assert (review.deleted, review.drawn, review.moved, review.confirmed) == (0, 0, 0, 1)
    # Accepting the same view again: every road is seen again, nothing changes.
    again = _preview(client, scene)
    second = client.post(f"/layers/teach/previews/{again}/accept", json={"network": "teach-net"},
                         headers=bearer("editor")).json()
    assert (second["added"], second["moved"], second["removed"]) == (0, 0, 0), second
    assert _segments("teach-net") == after
    # The first accept is a change set of the network, undone in one step.
    listed = client.get("/networks/teach-net/changes").json()
    assert any(s["id"] == counts["change_set"] and s["source"] ==
               f"preview {preview_id} of layer teach" for s in listed), listed
    reverted = client.post(f"/change-sets/{counts['change_set']}/revert",
                           headers=bearer("editor"))
    assert reverted.status_code == 200, reverted.text
    assert reverted.json()["reverted"] == counts["added"] + counts["removed"] + counts["moved"]
    back = _segments("teach-net")
    assert not added & set(back) and len(back) == len(before)


def test_a_preview_of_a_layer_reingested_meanwhile_stores_nothing(client, scene) -> None:
    asked = client.post("/layers/teach/previews", json={"bbox": scene["bbox"]},
                        headers=bearer("editor"))
    preview_id = asked.json()["id"]
    _reingest(scene)  # while the preview waits for its worker
    with pytest.raises(RoadsInputError, match="re-ingested while the preview ran"):
        tasks.run_job(preview_id)
    preview = client.get(f"/layers/teach/previews/{preview_id}").json()
    assert preview["status"] == "failed" and preview["result"] is None
    assert "was re-ingested while the preview ran" in preview["error"]
    assert scalar("SELECT count(*) FROM road_previews WHERE job_id = :id", id=preview_id) == 0
    accept = client.post(f"/layers/teach/previews/{preview_id}/accept",
                         json={"network": "teach-net"}, headers=bearer("editor"))
    assert accept.status_code == 409 and "preview again" in accept.json()["message"]


def test_accepting_a_preview_of_an_older_layer_version_is_a_conflict(client, scene) -> None:
    preview_id = _preview(client, scene)
    _reingest(scene)
    before = _segments("teach-net")
    answer = client.post(f"/layers/teach/previews/{preview_id}/accept",
                         json={"network": "teach-net"}, headers=bearer("editor"))
    assert answer.status_code == 409
    assert answer.json()["code"] == "StalePreview"
    assert answer.json()["message"].startswith("the layer changed since this preview")
    assert answer.json()["message"].endswith("preview again")
    assert _segments("teach-net") == before


def test_an_unknown_preview_is_not_found(client, scene: dict) -> None:
    assert client.get("/layers/teach/previews/999999").status_code == 404
    assert client.get("/layers/teach/previews/0").status_code == 400
    assert client.get("/layers/nope/previews/1").status_code == 404
