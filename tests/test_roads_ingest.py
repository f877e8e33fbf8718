"""``ugvmap ingest roads``: a stored raster layer's roads become a valid network in PostGIS."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
from click.testing import CliRunner
from pyproj import Transformer
from rasterio.transform import from_origin
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from ingest.raster.job import ingest_raster
from ingest.roads.synthetic import Scene, grid_scene, render
from tests.raster_synth import UTM33, utm_origin, write_tif

RES = 0.5
# A cross with a T arm, in pixels of a 400x300 image at 0.5 m/px.
ROADS = [[(20, 150), (380, 150)], [(200, 20), (200, 280)], [(60, 150), (60, 280)]]


def _layer(tmp_path: Path, slug: str, scene: Scene | None = None, res: float = RES
           ) -> Transformer:
    rgb, _ = render(scene or Scene((300, 400), roads=ROADS, seed=3))
    east, north = utm_origin(15.3, 48.31)
    transform = from_origin(round(east), round(north), res, res)
    write_tif(tmp_path / "scene.tif", np.moveaxis(rgb, -1, 0), UTM33, transform)
    ingest_raster([tmp_path / "scene.tif"], slug)
    to_lonlat = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)

    def pixel_to_lonlat(x: float, y: float) -> tuple[float, float]:
        return to_lonlat.transform(*(transform @ (x, y)))

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
    assert "(model classifier)" in result.output
    with session_scope() as session:
        rows = session.execute(text(
            "SELECT s.attrs->>'classifier', sum(s.length_m) FROM road_segments s "
            "JOIN networks n ON n.id = s.network_id WHERE n.name = 'zero-shot' "
            "GROUP BY 1")).all()
    assert [r[0] for r in rows] == ["model"]
    assert rows[0][1] > 2000
