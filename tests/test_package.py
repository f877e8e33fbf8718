"""``ugvmap export package``: a mission package round trip. Every archived raster tile equals
the served tile (read back by GDAL through rasterio, and byte for byte), the GeoPackage
re-imports (``ugvmap ingest network``) to the same segments and nodes, lanelet2 routes on the
package's map alone, and the manifest's checksums hold; bad requests change nothing."""

from __future__ import annotations

import hashlib
import json
import sqlite3
import zipfile

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.windows import Window
from sqlalchemy import text

from app.db.session import session_scope
from app.grid import tile_bounds
from cli.main import main
from ingest.network import RoadAttributes, RoadLine, write_network
from ingest.raster.job import ingest_raster
from testkit.raster_synth import decode_rgba, synthetic_utm
from tests.lanelet2_support import load
from tests.routing_support import unique, xy

pytestmark = pytest.mark.usefixtures("database_url")
CENTRE = (15.2017, 48.2990)  # inside the synthetic image (15.2..15.2036, 48.2981..48.3)
BBOX = "15.2008,48.2984,15.2026,48.2996"


def at(x: float, y: float) -> tuple[float, float]:
    return xy(x, y, CENTRE)


@pytest.fixture(scope="module")
def mission(tmp_path_factory, database_url):
    """A raster layer and a network over it: a two-way street with a one-way street leaving
    it at a traffic light, and a side road crossing the area's edge."""
    path, _ = synthetic_utm(tmp_path_factory.mktemp("img") / "ortho.tif")
    layer = unique("ortho")
    ingest_raster([path], layer)
    lines = [RoadLine([at(-60, 0), at(0, 0)], RoadAttributes(1, 1, 30.0, name="Main")),
             RoadLine([at(0, 0), at(60, 0)], RoadAttributes(2, 2, 30.0, name="Main")),
             RoadLine([at(0, 0), at(0, 40)], RoadAttributes(1, 0, 20.0, "forward",
                                                              name="Oneway")),
             RoadLine([at(60, 0), at(60, -200)], RoadAttributes(1, 1, name="Long"))]
    name = unique("mission")
    with session_scope() as session:
        write_network(session, name, lines)
    return layer, name


def run(*args: str):
    return CliRunner().invoke(main, ["export", "package", *args])


def test_package_round_trip(mission, tmp_path, client) -> None:
    layer, network = mission
    out = tmp_path / "pkg"
    r = run("--bbox", BBOX, "--layers", layer, "--network", network, "--out", str(out),
            "--minzoom", "16", "--maxzoom", "19")
    assert r.exit_code == 0, r.output
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["format"] == "ugvmap-mission-package"
    assert manifest["bbox"] == [float(v) for v in BBOX.split(",")]
    assert manifest["crs"]["tiles"].startswith("EPSG:3857")
    for entry in manifest["files"]:  # checksums and sizes hold
        data = (out / entry["path"]).read_bytes()
        assert hashlib.sha256(data).hexdigest() == entry["sha256"]
        assert len(data) == entry["bytes"]
    [info] = manifest["layers"]
    assert (info["minzoom"], info["maxzoom"]) == (16, 19) and info["tiles"] > 0

    # Every archived tile is the served tile, byte for byte (rows are TMS in MBTiles).
    archive = out / "rasters" / f"{layer}.mbtiles"
    with sqlite3.connect(archive) as db:
        meta = dict(db.execute("SELECT name, value FROM metadata"))
        rows = db.execute("SELECT zoom_level, tile_column, tile_row, tile_data FROM tiles"
                          ).fetchall()
    assert meta["format"] == "png" and (meta["minzoom"], meta["maxzoom"]) == ("16", "19")
    assert len(rows) == info["tiles"]
    served = {}
    for z, x, tms_row, data in rows:
        y = 2**z - 1 - tms_row
        r = client.get(f"/tiles/{layer}/{z}/{x}/{y}.png")
        assert r.status_code == 200 and r.content == data, (z, x, y)
        served[z, x, y] = r.content
    # GDAL reads the archive back (rasterio): each z19 tile's pixels are the served tile's.
    with rasterio.open(archive) as ds:
        assert ds.driver == "MBTiles" and ds.count == 4
        compared = 0
        for (z, x, y), body in served.items():
            if z != 19:
                continue
            left, _, _, top = tile_bounds(z, x, y)
            row, col = ds.index(left + ds.res[0] / 2, top - ds.res[1] / 2)
            assert 0 <= row <= ds.height - 256 and 0 <= col <= ds.width - 256
            pixels = np.moveaxis(ds.read(window=Window(col, row, 256, 256)), 0, -1)
            expected = decode_rgba(body)
            assert np.array_equal(pixels, expected), (z, x, y)
            compared += 1
        assert compared > 1

    # The network: whole segments meeting the area (the long road crosses its edge).
    gpkg = out / "network" / f"{network}.gpkg"
    again = unique("reimport")
    r = CliRunner().invoke(main, ["ingest", "network", str(gpkg), "--network", again])
    assert r.exit_code == 0, r.output
    with session_scope() as session:
        def rows_of(name: str) -> list[tuple]:
            return session.execute(_SEGMENTS, {"n": name}).all()

        def nodes_of(name: str) -> list[tuple]:
            return session.execute(_NODES, {"n": name}).all()

        assert rows_of(again) == rows_of(network) and len(rows_of(network)) == 4
        assert nodes_of(again) == nodes_of(network)
    assert manifest["network"]["segments"] == 4

    # The vehicle routes on the package alone: lanelet2 on its map and projector file.
    m = load(out / "lanelet2" / "lanelet2_map.osm")
    lanes = m.by_segment()
    ids = sorted({sid for sid, kind in lanes if kind == "forward"})
    west, east = ids[0], ids[1]
    assert m.graph.shortestPath(lanes[west, "forward"][0], lanes[east, "forward"][0])
    with sqlite3.connect(out / "network" / f"{network}.mbtiles") as db:
        assert db.execute("SELECT value FROM metadata WHERE name = 'format'"
                          ).fetchone() == ("pbf",)
        assert db.execute("SELECT count(*) FROM tiles").fetchone()[0] > 0


_SEGMENTS = text(
    "SELECT ST_AsText(s.geom), s.lanes_forward, s.lanes_backward, s.speed_limit_kph, "
    "s.oneway, s.road_class, s.name FROM road_segments s JOIN networks n "
    "ON n.id = s.network_id WHERE n.name = :n ORDER BY 1")
_NODES = text(
    "SELECT ST_AsText(r.geom), r.kind, r.traffic_light FROM road_nodes r JOIN networks n "
    "ON n.id = r.network_id WHERE n.name = :n ORDER BY 1")


def test_zip_package(mission, tmp_path) -> None:
    layer, network = mission
    out = tmp_path / "mission.zip"
    r = run("--bbox", BBOX, "--layers", layer, "--network", network, "--out", str(out),
            "--minzoom", "17", "--maxzoom", "18")
    assert r.exit_code == 0, r.output
    with zipfile.ZipFile(out) as archive:
        names = set(archive.namelist())
        manifest = json.loads(archive.read("manifest.json"))
        assert {f["path"] for f in manifest["files"]} | {"manifest.json"} == names
        assert f"rasters/{layer}.mbtiles" in names
        assert "lanelet2/map_projector_info.yaml" in names
    assert not list(tmp_path.glob(".*"))  # no temporary left
    # The terminal names what the user has, not the hidden folder it was built in.
    assert f"manifest.json and {len(names) - 1} files" in r.output, r.output
    assert "mission.zip/lanelet2/map_projector_info.yaml written" in r.output, r.output
    assert ".part" not in r.output, r.output


@pytest.mark.parametrize(("args", "message"), [
    (["--bbox", "10,50,10.01,50.01"], "has no segments within bbox"),
    (["--bbox", BBOX, "--layers", "no-such-layer"], "no raster layer"),
    (["--bbox", BBOX, "--maxzoom", "24", "--max-tiles", "100"], "more than --max-tiles"),
    (["--bbox", BBOX, "--minzoom", "19", "--maxzoom", "17"], "need 0 <= minzoom"),
    (["--bbox", "15.3,48.3,15.2,48.4"], "W < E"),
])
def test_bad_requests_write_nothing(mission, tmp_path, args, message) -> None:
    layer, network = mission
    layers = [] if "--layers" in args else ["--layers", layer]
    r = run(*args, *layers, "--network", network, "--out", str(tmp_path / "pkg"))
    assert r.exit_code == 1 and message in r.output, r.output
    assert list(tmp_path.iterdir()) == []


def test_raster_outside_the_area_and_existing_output(mission, tmp_path) -> None:
    layer, network = mission
    far = at(60, -190)  # on the long road, south of the image
    r = run("--bbox", f"{far[0] - 1e-4},{far[1] - 1e-4},{far[0] + 1e-4},{far[1] + 1e-4}",
            "--layers", layer, "--network", network, "--out", str(tmp_path / "p"))
    assert r.exit_code == 1 and f"layer {layer!r} has no data within bbox" in r.output
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "x").write_text("x")
    r = run("--bbox", BBOX, "--network", network, "--out", str(tmp_path / "taken"))
    assert r.exit_code == 1 and "already exists" in r.output
