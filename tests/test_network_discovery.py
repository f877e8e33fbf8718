"""Vector tiles a client can find by itself: the /networks listing, TileJSON 3.0.0 whose
vector_layers match what the tiles really carry, a MapLibre style that MapLibre's own
validator accepts, and metadata.json that GDAL's MVT driver opens."""

from __future__ import annotations

import json
import subprocess
import uuid
from pathlib import Path

import mapbox_vector_tile
import morecantile
import pytest
from sqlalchemy import text

from app.db.session import session_scope
from ingest.network import RoadAttributes, RoadLine, write_network

REPO = Path(__file__).resolve().parents[1]
STYLE_VALIDATOR = REPO / "app" / "web" / "node_modules" / ".bin" / "gl-style-validate"
ORIGIN = (30.0, 45.0)  # away from every other test's data
ZOOM = 16


@pytest.fixture(scope="module")
def network(database_url: str) -> str:
    """Two roads with every attribute set (confidence too), so each tile field is present in
    the tile."""
    name = f"disc-{uuid.uuid4().hex[:8]}"
    lon, lat = ORIGIN
    full = RoadAttributes(2, 1, 50.0, "none", "primary", False, "Main street", "asphalt", 7.5,
                          "w1")
    with session_scope() as session:
        summary = write_network(session, name, [
            RoadLine([(lon, lat), (lon + 0.002, lat)], full),
            RoadLine([(lon + 0.001, lat), (lon + 0.001, lat + 0.001)], full)])
        # As road extraction writes it (the importer has no confidence to give).
        session.execute(text("UPDATE road_segments SET confidence = 0.8 WHERE network_id = :n"),
                        {"n": summary.network_id})
    return name


def tile_of(z: int) -> morecantile.Tile:
    return morecantile.tms.get("WebMercatorQuad").tile(ORIGIN[0] + 0.001, ORIGIN[1], z)


def test_networks_listing(client, network) -> None:
    listing = client.get("/networks").json()["networks"]
    entry = next(n for n in listing if n["name"] == network)
    assert entry["segment_count"] == 3 and entry["node_count"] == 4
    assert entry["bounds"] == pytest.approx([30.0, 45.0, 30.002, 45.001])
    assert entry["version"] >= 1
    for key in ("self", "tilejson", "style", "metadata", "segments", "nodes"):
        assert client.get(entry["links"][key]).status_code == 200, key
    route = client.get(entry["links"]["route"], params={"points": "30.0,45.0;30.002,45.0"})
    assert route.json()["code"] == "Ok"
    assert client.get(f"/networks/{network}").json() == entry
    missing = client.get("/networks/no-such-network")
    assert missing.status_code == 404 and missing.json()["code"] == "NotFound"
    assert client.get("/networks/no-such-network/tilejson.json").status_code == 404


def test_tilejson_vector_layers_match_the_tiles(client, network) -> None:
    tj = client.get(f"/networks/{network}/tilejson.json").json()
    assert tj["tilejson"] == "3.0.0" and tj["scheme"] == "xyz"
    assert tj["bounds"] == pytest.approx([30.0, 45.0, 30.002, 45.001])
    layers = {layer["id"]: layer for layer in tj["vector_layers"]}
    assert layers["segments"]["fields"]["width_m"] == "Number"
    assert layers["segments"]["fields"]["is_junction"] == "Boolean"
    assert layers["segments"]["fields"]["name"] == "String"
    assert layers["nodes"]["minzoom"] == 12 and layers["segments"]["minzoom"] == 0
    t = tile_of(ZOOM)
    url = tj["tiles"][0].format(z=t.z, x=t.x, y=t.y).removeprefix("http://testserver")
    tile = client.get(url)
    assert tile.status_code == 200
    decoded = mapbox_vector_tile.decode(tile.content)
    assert set(decoded) == set(layers) - {"lanes"}  # no lane paint stored for this network
    for layer_id, layer in decoded.items():
        keys = {k for f in layer["features"] for k in f["properties"]}
        assert keys == set(layers[layer_id]["fields"]), layer_id
    pbf = client.get(url.replace(".mvt", ".pbf"))
    assert pbf.content == tile.content


def test_style_is_valid_maplibre_and_uses_the_tilejson(client, network, tmp_path: Path) -> None:
    style = client.get(f"/networks/{network}/style.json").json()
    source = style["sources"][network]
    assert source == {"type": "vector",
                      "url": f"http://testserver/networks/{network}/tilejson.json"}
    assert "glyphs" not in style and "sprite" not in style
    assert {layer["source-layer"] for layer in style["layers"]} == {"segments", "nodes",
                                                                     "lanes"}
    if not STYLE_VALIDATOR.exists():
        pytest.skip("npm ci has not installed MapLibre's style validator")
    path = tmp_path / "style.json"
    path.write_text(json.dumps(style))
    result = subprocess.run([str(STYLE_VALIDATOR), "--json", str(path)], capture_output=True,
                            text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr


def test_metadata_json_for_gdal(client, network) -> None:
    meta = client.get(f"/networks/{network}/tiles/metadata.json").json()
    assert meta["format"] == "pbf" and meta["maxzoom"] == "18"
    inner = json.loads(meta["json"])
    assert [layer["id"] for layer in inner["vector_layers"]] == ["segments", "nodes", "lanes"]
    stats = {a["attribute"]: a for layer in inner["tilestats"]["layers"]
             for a in layer["attributes"]}
    assert (stats["lanes_forward"]["min"], stats["lanes_forward"]["max"]) == (2, 2)


@pytest.mark.slow
def test_gdal_mvt_driver_reads_a_zoom_level(live_server: str, network) -> None:
    """``ogrinfo MVT:<tiles>/<z>`` reads <tiles>/metadata.json, then every tile of the
    network's bounds at that zoom (as .pbf, GDAL's default extension)."""
    result = subprocess.run(
        ["ogrinfo", "-ro", "-al", "-so", f"MVT:{live_server}/networks/{network}/tiles/{ZOOM}"],
        capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and not result.stderr.strip(), result.stderr
    out = result.stdout
    assert "Layer name: segments" in out and "Layer name: nodes" in out
    assert "Geometry: Multi Line String" in out
    assert "is_junction: Integer(Boolean)" in out and "name: String" in out
    counts = [int(line.split(":")[1]) for line in out.splitlines()
              if line.startswith("Feature Count")]
    assert counts[0] >= 3 and counts[1] >= 4


def _match(expression: list, road_class: str):
    """What a style's ``["match", ["get", "road_class"], labels, value, ..., fallback]`` gives
    for one class."""
    pairs = expression[2:-1]
    for labels, value in zip(pairs[::2], pairs[1::2], strict=True):
        if road_class in (labels if isinstance(labels, list) else [labels]):
            return value
    return expression[-1]


def test_style_keeps_a_city_readable_at_z15(client, network) -> None:
    """Helsinki at z15 was hard to read (issue 34): footways drawn like roads, a junction dot
    every few pixels. Ways for people are thin, sand-coloured, with a faint rim; junction dots
    start at z16 with the plain nodes; traffic lights still show from z12."""
    layers = {layer["id"]: layer for layer in
              client.get(f"/networks/{network}/style.json").json()["layers"]}
    width = layers["segments"]["paint"]["line-width"]
    assert width[:3] == ["interpolate", ["linear"], ["zoom"]]
    for zoom, by_class in zip(width[3::2], width[4::2], strict=True):
        for path in ("footway", "cycleway", "path", "steps", "pedestrian"):
            assert _match(by_class, path) < 0.5 * _match(by_class, "residential"), zoom
    colour = layers["segments"]["paint"]["line-color"]
    assert _match(colour, "footway") == _match(colour, "cycleway") != _match(colour, "service")
    rim = layers["segments-casing"]["paint"]["line-opacity"]
    assert _match(rim, "footway") < _match(rim, "residential")
    assert layers["nodes-junctions"]["minzoom"] == 16 and layers["nodes"]["minzoom"] == 16
    assert layers["nodes-traffic-lights"]["minzoom"] == 12
