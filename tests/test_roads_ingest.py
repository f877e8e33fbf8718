"""``ugvmap ingest roads``: a stored raster layer's roads become a valid network in PostGIS."""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import Geod, Transformer
from rasterio.transform import from_origin
from sqlalchemy import text

from app.db.session import session_scope
from app.network.settings import DEFAULT_SPEEDS_KPH
from cli.main import main
from ingest.queue import tasks
from ingest.raster.job import ingest_raster
from ingest.roads import layer as roads_layer
from ingest.roads.attributes import lanes
from ingest.roads.synthetic import Scene, grid_scene, render
from testkit.raster_synth import UTM33, utm_origin, write_tif

RES = 0.5
# A cross with a T arm, in pixels of a 400x300 image at 0.5 m/px.
ROADS = [[(20, 150), (380, 150)], [(200, 20), (200, 280)], [(60, 150), (60, 280)]]


def _scene_tif(path: Path, scene: Scene | None = None, res: float = RES,
               at: tuple[float, float] = (15.3, 48.31)) -> Callable:
    """Write the scene (default: the cross with a T arm) as a UTM 33N GeoTIFF whose corner is
    at lon/lat ``at``; return its pixel -> lon/lat function."""
    rgb, _ = render(scene or Scene((300, 400), roads=ROADS, seed=3))
    east, north = utm_origin(*at)
    transform = from_origin(round(east), round(north), res, res)
    write_tif(path, np.moveaxis(rgb, -1, 0), UTM33, transform)
    to_lonlat = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)

    def pixel_to_lonlat(x: float, y: float) -> tuple[float, float]:
        return to_lonlat.transform(*(transform @ (x, y)))

    return pixel_to_lonlat


def _layer(tmp_path: Path, slug: str, scene: Scene | None = None, res: float = RES
           ) -> Callable:
    pixel_to_lonlat = _scene_tif(tmp_path / "scene.tif", scene, res)
    ingest_raster([tmp_path / "scene.tif"], slug)
    return pixel_to_lonlat


def _box(pixel_to_lonlat, x0: int, y0: int, x1: int, y1: int) -> str:
    (lon0, lat1), (lon1, lat0) = pixel_to_lonlat(x0, y0), pixel_to_lonlat(x1, y1)
    return f"{lon0},{lat0},{lon1},{lat1}"


def test_ingest_roads_from_layer_writes_topology(database_url: str, tmp_path: Path) -> None:
    to_lonlat = _layer(tmp_path, "roads-scene")
    runner = CliRunner()
    result = runner.invoke(main, [
        "ingest", "roads", "--layer", "roads-scene", "--network", "scene-roads",
        "--train-box", _box(to_lonlat, 100, 146, 140, 154), "--classifier", "spectral"])
    assert result.exit_code == 0, result.output
    assert "extracted from layer roads-scene" in result.output
    with session_scope() as session:
        net = session.execute(text("SELECT id FROM networks WHERE name = 'scene-roads'")).scalar()
        ends = session.execute(text(
            "SELECT source_node, target_node FROM road_segments WHERE network_id = :n"),
            {"n": net}).all()
        junctions = session.execute(text(
            "SELECT ST_X(geom), ST_Y(geom) FROM road_nodes WHERE network_id = :n "
            "AND kind = 'junction'"), {"n": net}).all()
    degree = Counter(n for pair in ends for n in pair)
    # Cross (degree 4) at (200,150), T (degree 3) at (60,150); five dead ends.
    assert sorted(d for d in degree.values() if d > 1) == [3, 4]
    assert sum(1 for d in degree.values() if d == 1) == 5
    expected = [to_lonlat(200.5, 150.5), to_lonlat(60.5, 150.5)]
    for lon, lat in expected:
        assert min(abs(lon - x) + abs(lat - y) for x, y in junctions) < 2e-5  # ~1.5 m

    check = runner.invoke(main, ["network", "validate", "scene-roads"])
    assert check.exit_code == 0, check.output
    assert "1 connected components" in check.output and "piece 1: 6 segments" in check.output
    report = json.loads(runner.invoke(main, ["network", "validate", "scene-roads",
                                             "--json"]).output)
    assert report["ok"] and [p["segments"] for p in report["pieces"]] == [6]
    # The five road ends, where the scene's lines end (the skeleton stops short of a road's
    # end by up to its half width, 3 m).
    ends = [to_lonlat(x, y) for x, y in [(20, 150), (380, 150), (200, 20), (200, 280),
                                         (60, 280)]]
    found = [(d["lon"], d["lat"]) for d in report["dead_ends"]]
    assert len(found) == 5
    for lon, lat in ends:
        assert min(metres(lon, lat, x, y) for x, y in found) < 5.0
    west, _, east, _ = report["pieces"][0]["bbox"]
    assert west < ends[0][0] + 5e-5 and east > ends[1][0] - 5e-5


def metres(lon0: float, lat0: float, lon1: float, lat1: float) -> float:
    return float(Geod(ellps="WGS84").inv(lon0, lat0, lon1, lat1)[2])


def stored(network: str) -> list:
    with session_scope() as session:
        return session.execute(text(
            "SELECT s.road_class, s.speed_limit_kph, s.lanes_forward, s.lanes_backward, "
            "s.width_m, s.confidence, s.is_junction, s.attrs FROM road_segments s "
            "JOIN networks n ON n.id = s.network_id WHERE n.name = :n"), {"n": network}).all()


def test_attribute_rules_apply_and_override_per_network_and_job(database_url: str,
                                                                tmp_path: Path) -> None:
    to_lonlat = _layer(tmp_path, "roads-rules")
    runner = CliRunner()
    extract = ["ingest", "roads", "--layer", "roads-rules", "--network", "rules-net",
               "--train-box", _box(to_lonlat, 100, 146, 140, 154), "--classifier", "spectral",
               "--replace"]
    result = runner.invoke(main, extract)
    assert result.exit_code == 0, result.output
    assert "classes: " in result.output and "confidence mean" in result.output
    rows = stored("rules-net")
    assert len(rows) == 6
    for road_class, speed, forward, backward, width, confidence, junction, attrs in rows:
        assert forward == backward == lanes(width, 3.5)[0]  # symmetric, from the width
        assert speed == DEFAULT_SPEEDS_KPH[road_class]
        assert 0.5 < confidence <= 1.0 and not junction
        assert 0 <= attrs["through"] <= 1 and attrs["classifier"] == "spectral"
    # The segment between the two junctions carries every through route: the busiest.
    assert max(r.attrs["through"] for r in rows) == 1.0

    speeds = tmp_path / "speeds.csv"
    speeds.write_text("road_class,speed_kph\nresidential,25\ntertiary,35\nservice,12\n")
    classes = tmp_path / "classes.json"
    classes.write_text(json.dumps([{"road_class": "track"}]))
    settings = runner.invoke(main, ["network", "settings", "rules-net", "--lane-width", "2",
                                    "--speed-table", str(speeds)])
    assert settings.exit_code == 0 and "lane width: 2 m (network)" in settings.output
    assert "residential: 25 (network)" in settings.output
    assert runner.invoke(main, extract).exit_code == 0
    rows = stored("rules-net")
    assert {r.speed_limit_kph for r in rows} <= {25.0, 35.0, 12.0}
    assert all(r.lanes_forward == lanes(r.width_m, 2.0)[0] for r in rows)
    assert any(r.attrs.get("lanes:both_ways") == 1 for r in rows) \
        == any(lanes(r.width_m, 2.0)[2] for r in rows)

    # The job's options win over the network's, which stay stored.
    result = runner.invoke(main, [*extract, "--lane-width", "1.5", "--class-table",
                                  str(classes), "--speed-table", str(speeds)])
    assert result.exit_code == 0, result.output
    rows = stored("rules-net")
    assert {(r.road_class, r.speed_limit_kph) for r in rows} == {("track", 15.0)}
    assert all(r.lanes_forward == lanes(r.width_m, 1.5)[0] for r in rows)
    shown = json.loads(runner.invoke(main, ["network", "settings", "rules-net",
                                            "--json"]).output)
    assert shown["overrides"] == {"lane_width_m": 2.0, "speed_kph": {
        "residential": 25.0, "tertiary": 35.0, "service": 12.0}}

    bad = tmp_path / "bad.csv"
    bad.write_text("road_class,speed_kph\nhighway,30\n")
    before = stored("rules-net")
    result = runner.invoke(main, [*extract, "--speed-table", str(bad)])
    assert result.exit_code == 1 and "'highway' is not a road class" in result.output
    assert stored("rules-net") == before


def test_queued_extraction_applies_the_job_rules(database_url: str, tmp_path: Path) -> None:
    to_lonlat = _layer(tmp_path, "roads-queued")
    speeds = tmp_path / "speeds.json"
    speeds.write_text(json.dumps({"residential": 22, "tertiary": 22, "service": 22,
                                  "secondary": 22}))
    result = CliRunner().invoke(main, [
        "ingest", "roads", "--layer", "roads-queued", "--network", "queued-rules",
        "--train-box", _box(to_lonlat, 100, 146, 140, 154), "--classifier", "spectral",
        "--speed-table", str(speeds), "--queue"])
    assert result.exit_code == 0 and "queued job" in result.output, result.output
    job_id = int(result.output.split()[2])
    tasks.run_job(job_id)
    with session_scope() as session:
        status, message = session.execute(text(
            "SELECT status, message FROM ingest_jobs WHERE id = :id"), {"id": job_id}).one()
    assert status == "succeeded" and "6 segments" in message, message
    assert {r.speed_limit_kph for r in stored("queued-rules")} == {22.0}


def test_ingest_roads_bad_input_changes_nothing(database_url: str, tmp_path: Path) -> None:
    _layer(tmp_path, "roads-scene-2")
    runner = CliRunner()
    unknown = runner.invoke(main, ["ingest", "roads", "--layer", "no-such-layer",
                                   "--network", "x", "--train-box", "15,48,15.1,48.1"])
    assert unknown.exit_code == 1 and "no raster layer" in unknown.output
    far = runner.invoke(main, ["ingest", "roads", "--layer", "roads-scene-2", "--network",
                               "never-written", "--train-box", "10,10,10.001,10.001"])
    assert far.exit_code == 1 and "does not cover any road pixel" in far.output
    assert "Traceback" not in far.output + unknown.output
    with session_scope() as session:
        assert session.execute(text(
            "SELECT count(*) FROM networks WHERE name = 'never-written'")).scalar() == 0


def test_ingest_roads_zero_shot_uses_the_road_model(database_url: str, tmp_path: Path) -> None:
    # A 400 m town at 1 m/px: four streets each way, roofs in the blocks (~3.2 km of road).
    _layer(tmp_path, "roads-scene-3", grid_scene(400, 100, 8), res=1.0)
    result = CliRunner().invoke(main, ["ingest", "roads", "--layer", "roads-scene-3",
                                       "--network", "zero-shot"])
    assert result.exit_code == 0, result.output
    assert "(model classifier, sample: none)" in result.output
    with session_scope() as session:
        rows = session.execute(text(
            "SELECT s.attrs->>'classifier', sum(s.length_m) FROM road_segments s "
            "JOIN networks n ON n.id = s.network_id WHERE n.name = 'zero-shot' "
            "GROUP BY 1")).all()
    assert [r[0] for r in rows] == ["model"]
    assert rows[0][1] > 2000


def test_a_layer_of_two_far_apart_sources_is_extracted_per_area(
        database_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two 200 x 150 m scenes 1,000 km apart in one layer: their common bounding box would be
    a mosaic of billions of pixels, each area alone is small."""
    north = _scene_tif(tmp_path / "north.tif")
    south = _scene_tif(tmp_path / "south.tif", at=(16.0, 39.5))
    ingest_raster([tmp_path / "north.tif", tmp_path / "south.tif"], "two-areas", add=True)
    runner = CliRunner()
    roads = ["ingest", "roads", "--layer", "two-areas", "--classifier", "spectral"]
    one_box = ["--train-box", _box(north, 100, 146, 140, 154)]
    # A per-job classifier has nothing to learn from in an area the sample does not touch.
    unsampled = runner.invoke(main, [*roads, "--network", "never", *one_box])
    assert unsampled.exit_code == 1, unsampled.output
    assert ("the training sample covers no road in the area of south.tif, one of the "
            "layer's 2 separate areas") in unsampled.output
    result = runner.invoke(main, [*roads, "--network", "two-areas", *one_box,
                                  "--train-box", _box(south, 100, 146, 140, 154)])
    assert result.exit_code == 0, result.output
    assert "extracted from layer two-areas in 2 separate areas (spectral" in result.output
    report = json.loads(runner.invoke(main, ["network", "validate", "two-areas",
                                             "--json"]).output)
    assert [p["segments"] for p in report["pieces"]] == [6, 6]
    with session_scope() as session:
        assert session.execute(text(
            "SELECT count(*) FROM networks WHERE name = 'never'")).scalar() == 0

    # One area beyond the limit says what the limit is.
    monkeypatch.setattr(roads_layer, "MAX_MOSAIC_SIDE_PX", 100)
    monkeypatch.setattr(roads_layer, "MAX_MOSAIC_PX", 100 * 100)
    big = runner.invoke(main, [*roads, "--network", "never", *one_box])
    assert big.exit_code == 1
    assert "the area of south.tif would be one " in big.output
    assert "mosaic at its finest source resolution, more than the 100 x 100 px one " \
           "extraction holds in memory" in big.output
