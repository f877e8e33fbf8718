"""A layer's labels (``/layers/{slug}/labels``, ``ugvmap layers labels``): who may write them,
what is refused (with nothing written), and that they go with their layer."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jsonschema
import pytest
from click.testing import CliRunner
from pyproj import Transformer
from sqlalchemy import text

from app.db.session import get_engine, session_scope
from app.errors import InvalidValueError
from app.labels import store
from app.tiles.catalog import delete_layer
from cli.main import main
from ingest.raster.job import ingest_raster
from testkit.network_helpers import bearer
from testkit.raster_synth import UTM33, synthetic_utm

SLUG = "labels-scene"
Lonlat = Callable[[float, float], list[float]]


@pytest.fixture(scope="module")
def lonlat(database_url: str, tmp_path_factory: pytest.TempPathFactory) -> Lonlat:
    """A 100 x 100 m layer (200 px at 0.5 m); its pixel -> [lon, lat]."""
    path, transform = synthetic_utm(tmp_path_factory.mktemp("labels") / "scene.tif",
                                    width=200, height=200, res=0.5)
    ingest_raster([path], SLUG)
    to_lonlat = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)
    return lambda x, y: list(to_lonlat.transform(*(transform @ (x, y))))


@pytest.fixture()
def editor() -> dict[str, str]:
    return bearer("editor")


@pytest.fixture(autouse=True)
def no_labels(lonlat: Lonlat) -> None:
    with session_scope() as session:
        store.clear_labels(session, SLUG)


def line(lonlat: Lonlat, *pixels: tuple[float, float], label: str = "road") -> dict[str, Any]:
    return {"type": "Feature", "properties": {"label": label},
            "geometry": {"type": "LineString", "coordinates": [lonlat(*p) for p in pixels]}}


def area(lonlat: Lonlat, x0: float, y0: float, x1: float, y1: float,
         label: str = "not_road") -> dict[str, Any]:
    ring = [lonlat(x0, y0), lonlat(x1, y0), lonlat(x1, y1), lonlat(x0, y1), lonlat(x0, y0)]
    return {"type": "Feature", "properties": {"label": label},
            "geometry": {"type": "Polygon", "coordinates": [ring]}}


def collection(*features: dict[str, Any]) -> dict[str, Any]:
    return {"type": "FeatureCollection", "features": list(features)}


def stored() -> list[tuple[str, str, str]]:
    with get_engine().connect() as conn:
        return [tuple(r) for r in conn.execute(text(
            "SELECT l.label, GeometryType(l.geom), l.created_by FROM layer_labels l "
            "JOIN layers y ON y.id = l.layer_id WHERE y.slug = :s ORDER BY l.id"),
            {"s": SLUG})]


def test_editors_write_labels_everyone_reads_them(client, lonlat: Lonlat,
                                                  editor: dict[str, str]) -> None:
    url = f"/layers/{SLUG}/labels"
    body = collection(line(lonlat, (10, 100), (190, 100)),
                      line(lonlat, (20, 20), (60, 60), label="not_road"),
                      area(lonlat, 120, 120, 180, 180))
    missing = client.post(url, json=body)
    assert missing.status_code == 401 and missing.headers["WWW-Authenticate"]
    viewer = client.post(url, json=body, headers=bearer("viewer"))
    assert viewer.status_code == 403 and viewer.json()["code"] == "Forbidden"
    assert stored() == []

    created = client.post(url, json=body, headers=editor)
    assert created.status_code == 201, created.text
    assert created.headers["content-type"] == "application/geo+json"
    features = created.json()["features"]
    assert [f["properties"]["label"] for f in features] == ["road", "not_road", "not_road"]
    name = features[0]["properties"]["created_by"]
    assert name.startswith("editor-")
    assert stored() == [("road", "LINESTRING", name), ("not_road", "LINESTRING", name),
                        ("not_road", "POLYGON", name)]
    # A single Feature is a batch of one; an admin may write too.
    one = client.post(url, json=line(lonlat, (100, 10), (100, 190)), headers=bearer("admin"))
    assert one.status_code == 201 and len(one.json()["features"]) == 1

    listed = client.get(url)  # public, as the layer itself
    assert listed.status_code == 200
    got = listed.json()["features"]
    assert [f["id"] for f in got] == [f["id"] for f in features] + [one.json()["features"][0]["id"]]
    assert got[0]["geometry"]["coordinates"][0] == pytest.approx(lonlat(10, 100), abs=1e-9)

    first = features[0]["id"]
    assert client.delete(f"{url}/{first}").status_code == 401
    assert client.delete(f"{url}/{first}", headers=bearer("viewer")).status_code == 403
    assert client.delete(f"{url}/{first}", headers=editor).status_code == 204
    gone = client.delete(f"{url}/{first}", headers=editor)
    assert gone.status_code == 404 and gone.json()["code"] == "NotFound"
    assert len(stored()) == 3
    assert client.delete(url, headers=bearer("viewer")).status_code == 403
    typo = client.delete(f"{url}?label=road", headers=editor)  # not a filter: refused
    assert typo.status_code == 400 and "unknown query parameter" in typo.json()["message"]
    assert len(stored()) == 3
    cleared = client.delete(url, headers=editor)
    assert cleared.status_code == 200 and cleared.json() == {"deleted": 3}
    assert stored() == [] and client.get(url).json()["features"] == []


def _bad_bodies(lonlat: Lonlat) -> dict[str, tuple[Any, str]]:
    good = line(lonlat, (10, 100), (190, 100))
    far = [[lonlat(10, 100)[0] + 0.01, lonlat(10, 100)[1]], lonlat(190, 100)]
    bowtie = area(lonlat, 20, 20, 80, 80)
    ring = bowtie["geometry"]["coordinates"][0]
    ring[1], ring[2] = ring[2], ring[1]
    return {
        "off the imagery": (collection(good, {**good, "geometry": {
            "type": "LineString", "coordinates": far}}), "outside the imagery"),
        "a road area": (area(lonlat, 20, 20, 80, 80, label="road"),
                        "a road label must be a GeoJSON LineString"),
        "a point": ({**good, "geometry": {"type": "Point", "coordinates": lonlat(5, 5)}},
                    "must be a GeoJSON LineString"),
        "no geometry": ({**good, "geometry": None}, "must be a GeoJSON LineString"),
        "self-crossing area": (bowtie, "invalid geometry: Self-intersection"),
        "one position twice": ({**good, "geometry": {"type": "LineString", "coordinates": [
            lonlat(5, 5), lonlat(5, 5)]}}, "two different positions"),
        "empty line": ({**good, "geometry": {"type": "LineString", "coordinates": []}},
                       "the geometry is empty"),
        "unknown label": (collection(good, {**good, "properties": {"label": "maybe"}}),
                          "features[1].properties.label: must be one of road, not_road"),
        "no label": ({**good, "properties": {}}, "must be one of road, not_road"),
        "out-of-range position": ({**good, "geometry": {"type": "LineString", "coordinates": [
            [200, 10], [10, 10]]}}, "lon -180..180"),
        "text positions": ({**good, "geometry": {"type": "LineString", "coordinates": [
            ["a", "b"], [10, 10]]}}, "pairs of finite numbers"),
        "not GeoJSON": ({"labels": [good]}, "must be a GeoJSON Feature or FeatureCollection"),
        "empty collection": (collection(), "has no features"),
        "too many in one request": (collection(*[good] * (store.MAX_PER_REQUEST + 1)),
                                    f"at most {store.MAX_PER_REQUEST}"),
    }


@pytest.mark.parametrize("case", ["off the imagery", "a road area", "a point", "no geometry",
                                  "self-crossing area", "one position twice", "empty line",
                                  "unknown label", "no label", "out-of-range position",
                                  "text positions", "not GeoJSON", "empty collection",
                                  "too many in one request"])
def test_bad_labels_are_refused_with_nothing_written(client, lonlat: Lonlat,
                                                     editor: dict[str, str], case: str) -> None:
    body, says = _bad_bodies(lonlat)[case]
    response = client.post(f"/layers/{SLUG}/labels", json=body, headers=editor)
    assert response.status_code == 422, response.text
    answer = response.json()
    assert answer["code"] == "InvalidValue"
    assert says in answer["message"] + json.dumps(answer.get("errors")), answer
    assert stored() == []


def test_a_full_layer_takes_no_more(client, lonlat: Lonlat, editor: dict[str, str],
                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(store, "MAX_PER_LAYER", 3)
    url = f"/layers/{SLUG}/labels"
    two = collection(*[line(lonlat, (10, 10 + i), (190, 10 + i)) for i in range(2)])
    assert client.post(url, json=two, headers=editor).status_code == 201
    refused = client.post(url, json=two, headers=editor)
    assert refused.status_code == 422 and "limit of 3" in refused.json()["message"]
    assert len(stored()) == 2


def test_two_editors_cannot_pass_the_layer_limit_together(lonlat: Lonlat,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The second batch waits for the first to commit (the layer is locked while a batch is
    counted), then counts it and is refused: never two batches each seeing room for itself."""
    monkeypatch.setattr(store, "MAX_PER_LAYER", 3)
    two = store.parse_labels(collection(*[line(lonlat, (10, 10 + i), (190, 10 + i))
                                          for i in range(2)]))
    pid: list[int] = []
    started = threading.Event()
    outcome: list[BaseException | None] = []

    def second() -> None:
        try:
            with session_scope() as session:
                pid.append(session.execute(text("SELECT pg_backend_pid()")).scalar_one())
                started.set()
                store.add_labels(session, SLUG, two, "second")
            outcome.append(None)
        except BaseException as exc:  # handed to the test's thread
            outcome.append(exc)
            started.set()

    worker = threading.Thread(target=second)
    with session_scope() as session:
        store.add_labels(session, SLUG, two, "first")
        worker.start()
        assert started.wait(30) and pid
        deadline = time.monotonic() + 30
        with get_engine().connect() as conn:  # until the second batch waits for the lock
            while conn.execute(text("SELECT wait_event_type FROM pg_stat_activity "
                                    "WHERE pid = :pid"), {"pid": pid[0]}).scalar() != "Lock":
                assert time.monotonic() < deadline, "the second batch never waited"
                conn.rollback()
    worker.join(60)
    assert len(outcome) == 1 and isinstance(outcome[0], InvalidValueError)
    assert "limit of 3" in outcome[0].message
    assert [r[2] for r in stored()] == ["first", "first"]


def test_the_api_document_describes_the_label_urls(client, lonlat: Lonlat,
                                                   editor: dict[str, str]) -> None:
    paths = client.get("/openapi.json").json()["paths"]
    labels, one = paths["/layers/{slug}/labels"], paths["/layers/{slug}/labels/{label_id}"]
    assert "security" not in labels["get"]  # public, as the layer
    post = labels["post"]
    listed = labels["get"]["responses"]["200"]["content"]["application/geo+json"]["schema"]
    # The labels' own shape, not OGC API's items page (no numberMatched, no links).
    assert listed["required"] == ["type", "features", "numberReturned"]
    assert post["responses"]["201"]["content"]["application/geo+json"]["schema"] == listed
    url = f"/layers/{SLUG}/labels"
    created = client.post(url, json=area(lonlat, 20, 20, 80, 80), headers=editor)
    jsonschema.validate(created.json(), listed)  # what is served is what is declared
    jsonschema.validate(client.get(url).json(), listed)
    assert post["security"] == [{"bearer": []}]
    assert set(post["responses"]) >= {"201", "400", "401", "403", "404", "413", "415", "422"}
    body = post["requestBody"]["content"]["application/geo+json"]["schema"]["oneOf"]
    assert body[0]["properties"]["properties"]["properties"]["label"]["enum"] == [
        "road", "not_road"]
    assert set(one["delete"]["responses"]) >= {"204", "401", "403", "404"}
    assert set(labels["delete"]["responses"]) >= {"200", "401", "403", "404"}


def test_unknown_layer_and_bad_requests(client, lonlat: Lonlat, editor: dict[str, str]) -> None:
    body = line(lonlat, (10, 100), (190, 100))
    for response in (client.get("/layers/no-such/labels"),
                     client.post("/layers/no-such/labels", json={}, headers=editor),
                     client.delete("/layers/no-such/labels/1", headers=editor),
                     client.delete("/layers/no-such/labels", headers=editor)):
        assert response.status_code == 404 and response.json()["code"] == "LayerNotFound"
    url = f"/layers/{SLUG}/labels"
    assert client.delete(f"{url}/x", headers=editor).status_code == 400
    assert client.delete(f"{url}/0", headers=editor).status_code == 400
    wrong_type = client.post(url, content=json.dumps(body), headers={
        **editor, "Content-Type": "text/plain"})
    assert wrong_type.status_code == 415
    not_json = client.post(url, content=b"{", headers={**editor,
                                                       "Content-Type": "application/json"})
    assert not_json.status_code == 400
    assert stored() == []


def test_labels_go_with_their_layer(client, lonlat: Lonlat, editor: dict[str, str],
                                    tmp_path: Path) -> None:
    path, _ = synthetic_utm(tmp_path / "other.tif", width=100, height=100, res=0.5)
    ingest_raster([path], "labels-doomed")
    with session_scope() as session:
        store.add_labels(session, "labels-doomed",
                         store.parse_labels(line(lonlat, (10, 10), (90, 90))), "test")
        doomed = store.layer_id(session.connection(), "labels-doomed")

    def held() -> int:
        with get_engine().connect() as conn:
            return conn.execute(text("SELECT count(*) FROM layer_labels WHERE layer_id = :id"),
                                {"id": doomed}).scalar_one()

    assert held() == 1
    with get_engine().begin() as conn:
        delete_layer(conn, "labels-doomed")
    assert held() == 0


def test_cli_lists_adds_deletes_and_clears(lonlat: Lonlat, tmp_path: Path) -> None:
    runner = CliRunner()
    lines = tmp_path / "lines.geojson"
    plain = line(lonlat, (10, 100), (190, 100))
    plain["properties"] = {}
    lines.write_text(json.dumps(collection(plain, line(lonlat, (20, 20), (60, 60),
                                                       label="not_road"))))
    added = runner.invoke(main, ["layers", "labels", SLUG, "--add", str(lines),
                                 "--label", "road"])
    assert added.exit_code == 0, added.output
    assert added.output.startswith(f"added 2 labels to layer {SLUG}")
    assert [r[:2] for r in stored()] == [("road", "LINESTRING"), ("not_road", "LINESTRING")]
    assert stored()[0][2].startswith("cli:")

    unlabelled = runner.invoke(main, ["layers", "labels", SLUG, "--add", str(lines)])
    assert unlabelled.exit_code == 1
    assert "InvalidValue: 1 of 2 labels refused, nothing stored; features[0].properties" \
        in unlabelled.output
    listed = runner.invoke(main, ["layers", "labels", SLUG]).output.splitlines()
    assert [row.split("\t")[1:3] for row in listed] == [["road", "LineString"],
                                                        ["not_road", "LineString"]]
    first = listed[0].split("\t")[0]
    deleted = runner.invoke(main, ["layers", "labels", SLUG, "--delete", first])
    assert deleted.exit_code == 0 and len(stored()) == 1
    again = runner.invoke(main, ["layers", "labels", SLUG, "--delete", first])
    assert again.exit_code == 1 and f"has no label {first}" in again.output
    cleared = runner.invoke(main, ["layers", "labels", SLUG, "--clear"])
    assert cleared.output.strip() == f"deleted 1 labels of layer {SLUG}" and stored() == []
    unknown = runner.invoke(main, ["layers", "labels", "no-such"])
    assert unknown.exit_code == 1 and "LayerNotFound: no raster layer 'no-such'" in unknown.output
    garbage = tmp_path / "garbage.geojson"
    garbage.write_text("{")
    broken = runner.invoke(main, ["layers", "labels", SLUG, "--add", str(garbage)])
    assert broken.exit_code == 1 and "not a GeoJSON file" in broken.output
