"""Export/import round trips are lossless: geometry (exact coordinates, direction) and every
attribute of every segment and node, for GeoJSON, GeoPackage and OSM. GeoJSON keeps segments
and nodes in two files; OSM files hold new objects (negative ids, no version), checked with
osmium."""

from __future__ import annotations

import json
import shutil
import subprocess
import uuid
from dataclasses import asdict
from pathlib import Path

import pytest
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from ingest.network import NodePoint, RoadAttributes, RoadLine, import_network, write_network
from ingest.network.exporter import load_network

# (format, --out, the file to import back)
FORMATS = [("geojson", "x.geojson", "x.segments.geojson"), ("gpkg", "x.gpkg", "x.gpkg"),
           ("osm", "x.osm.pbf", "x.osm.pbf"), ("osm", "x.osm", "x.osm")]


def snapshot(network: str) -> tuple[list, list]:
    """The network without its database ids: what a round trip must preserve."""
    with session_scope() as s:
        segments, nodes = load_network(s, network)
    by_id = {n.id: n.coord for n in nodes}
    segs = sorted((tuple(seg.coords), by_id[seg.source_node], by_id[seg.target_node],
                   round(seg.length_m, 6), repr(sorted(asdict(seg.attributes).items())))
                  for seg in segments)
    return segs, sorted((n.coord, n.kind, n.traffic_light, n.external_id) for n in nodes)


def varied_network(osm_safe: bool) -> str:
    """Every attribute type (extraction's confidence too), nulls, unicode, a one-way, a bridge
    crossing without a junction, a loop and two traffic lights (one without an external id).
    OSM stores 1e-7 degree fixed point and tags are strings, so the OSM variant has 7-decimal
    coordinates and string attrs."""
    name = f"varied-{uuid.uuid4().hex[:8]}"
    attrs = {"bridge": "yes", "layer": "1"} if osm_safe else {"bridge": True, "n": [1, {"a": 2}]}
    fine = 24.9012346 if osm_safe else 24.9012345678901
    lines = [
        RoadLine([(24.9, 60.1), (fine, 60.1), (24.9024, 60.1001)],
                 RoadAttributes(3, 0, 60.0, "forward", "primary", False, "Mannerheimintie ä'\"",
                                "asphalt", 12.5, "w1", {"ref": "1"}, confidence=0.8125)),
        RoadLine([(24.9024, 60.1001), (24.903, 60.1005), (24.9024, 60.101), (24.9024, 60.1001)],
                 RoadAttributes(1, 1, None, "none", "residential", True, None, None, None, None,
                                {})),
        RoadLine([(24.9012, 60.0995), (24.9012, 60.1005)],  # crosses the first: a bridge
                 RoadAttributes(0, 2, 30.5, "backward", "secondary", False, "Silta", None, None,
                                "w3", attrs, confidence=0.0)),
    ]
    with session_scope() as s:
        write_network(s, name, lines, node_crossings=False,
                      node_points=[NodePoint((24.9024, 60.1001), True, "n42"),
                                   NodePoint((24.9012, 60.0995), True, None)])
    return name


def export(network: str, fmt: str, out: Path) -> None:
    result = CliRunner().invoke(main, ["export", "network", network, "--format", fmt,
                                       "--out", str(out)])
    assert result.exit_code == 0, result.output


@pytest.mark.parametrize(("fmt", "filename", "imported"), FORMATS)
def test_round_trip_is_lossless(database_url: str, tmp_path: Path, fmt: str,
                                filename: str, imported: str) -> None:
    original = varied_network(osm_safe=fmt == "osm")
    export(original, fmt, tmp_path / filename)
    copy = f"{original}-copy"
    result = CliRunner().invoke(main, ["ingest", "network", str(tmp_path / imported),
                                       "--network", copy])
    assert result.exit_code == 0, result.output
    assert snapshot(copy) == snapshot(original)
    before = snapshot(original)
    assert (len(before[0]), len(before[1]), sum(n[2] for n in before[1])) == (3, 4, 2)


def test_geojson_export_keeps_segments_and_nodes_apart(database_url: str,
                                                       tmp_path: Path) -> None:
    network = varied_network(osm_safe=False)
    export(network, "geojson", tmp_path / "roads.geojson")
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "roads.nodes.geojson", "roads.segments.geojson"]
    segments = json.loads((tmp_path / "roads.segments.geojson").read_text())
    nodes = json.loads((tmp_path / "roads.nodes.geojson").read_text())
    assert {f["geometry"]["type"] for f in segments["features"]} == {"LineString"}
    assert {f["geometry"]["type"] for f in nodes["features"]} == {"Point"}
    assert (len(segments["features"]), len(nodes["features"])) == (3, 4)
    # GDAL sees one geometry type per file, as QGIS and ogr2ogr expect
    info = subprocess.run(["ogrinfo", "-ro", "-so", "-al", str(tmp_path / "roads.nodes.geojson")],
                          capture_output=True, text=True, check=True).stdout
    assert "Geometry: Point" in info and "Feature Count: 4" in info
    alone = CliRunner().invoke(main, ["ingest", "network", str(tmp_path / "roads.nodes.geojson"),
                                      "--network", f"{network}-nodes"])
    assert alone.exit_code == 1 and "import roads.segments.geojson" in alone.output


@pytest.mark.skipif(shutil.which("osmium") is None, reason="osmium-tool is not installed")
@pytest.mark.parametrize("filename", ["x.osm", "x.osm.pbf"])
def test_osm_export_holds_new_objects(database_url: str, tmp_path: Path,
                                      filename: str) -> None:
    """JOSM and osmium read objects not yet in OSM as negative ids without a version."""
    out = tmp_path / filename
    export(varied_network(osm_safe=True), "osm", out)
    info = json.loads(subprocess.run(["osmium", "fileinfo", "-e", "-j", str(out)],
                                     capture_output=True, text=True, check=True).stdout)
    assert info["data"]["count"]["ways"] == 3 and info["data"]["count"]["nodes"] >= 4
    assert info["data"]["maxid"]["nodes"] < 0 and info["data"]["maxid"]["ways"] < 0
    assert subprocess.run(["osmium", "check-refs", str(out)],
                          capture_output=True).returncode == 0  # every way's nodes are there
    opl = subprocess.run(["osmium", "cat", "-f", "opl", str(out)], capture_output=True,
                         text=True, check=True).stdout.splitlines()
    assert opl and all(line.split()[1] == "v0" for line in opl)  # no version
    if filename.endswith(".osm"):
        objects = [line for line in out.read_text().splitlines()
                   if line.lstrip().startswith(("<node", "<way"))]
        assert objects and not any("version=" in line for line in objects)


@pytest.mark.slow
@pytest.mark.parametrize(("fmt", "filename"), [("gpkg", "h.gpkg"), ("osm", "h.osm.pbf")])
def test_real_network_round_trip(database_url: str, shared_data: Path, tmp_path: Path,
                                 fmt: str, filename: str) -> None:
    name = f"hel-{uuid.uuid4().hex[:6]}"
    with session_scope() as s:
        import_network(s, shared_data / "osm" / "Helsinki.osm.pbf", name)
    out = tmp_path / filename
    export(name, fmt, out)
    assert CliRunner().invoke(main, ["ingest", "network", str(out), "--network",
                                     f"{name}-copy"]).exit_code == 0
    assert snapshot(f"{name}-copy") == snapshot(name)


def test_export_errors_are_one_line(database_url: str, tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["export", "network", "missing", "--format", "geojson",
                                       "--out", str(tmp_path / "x.geojson")])
    assert result.exit_code == 1 and "does not exist" in result.output
    assert not list(tmp_path.iterdir())


def test_josm_file_with_new_objects_imports(database_url: str, tmp_path: Path) -> None:
    """A way drawn in JOSM (negative ids, no version) onto an existing OSM node: both ways
    import, connected, and only the OSM way gets an external id."""
    path = tmp_path / "edited.osm"
    path.write_text("""<?xml version='1.0' encoding='UTF-8'?>
<osm version='0.6' generator='JOSM'>
  <node id='100' version='3' visible='true' lat='60.1' lon='24.9' />
  <node id='101' version='1' visible='true' lat='60.1' lon='24.901' />
  <node id='-1' action='modify' visible='true' lat='60.101' lon='24.901' />
  <way id='200' version='2' visible='true'>
    <nd ref='100' /><nd ref='101' /><tag k='highway' v='residential' />
  </way>
  <way id='-5' action='modify' visible='true'>
    <nd ref='101' /><nd ref='-1' /><tag k='highway' v='service' />
  </way>
</osm>
""")
    name = f"josm-{uuid.uuid4().hex[:6]}"
    result = CliRunner().invoke(main, ["ingest", "network", str(path), "--network", name])
    assert result.exit_code == 0, result.output
    with session_scope() as s:
        segments, nodes = load_network(s, name)
    assert sorted((seg.attributes.road_class, seg.attributes.external_id) for seg in segments) \
        == [("residential", "w200"), ("service", None)]
    assert len(nodes) == 3  # joined at node 101


def test_confidence_outside_zero_to_one_is_refused(database_url: str, tmp_path: Path) -> None:
    """A hand-edited export with a confidence of 1.5 is a clear error, not a database one."""
    path = tmp_path / "bad.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"road_class": "residential", "confidence": 1.5},
        "geometry": {"type": "LineString", "coordinates": [[24.9, 60.1], [24.901, 60.1]]}}]}))
    name = f"bad-{uuid.uuid4().hex[:6]}"
    result = CliRunner().invoke(main, ["ingest", "network", str(path), "--network", name])
    assert result.exit_code == 1, result.output
    assert "confidence must be a number from 0 to 1" in result.output
    with session_scope() as s:
        assert s.execute(text("SELECT count(*) FROM networks WHERE name = :n"),
                         {"n": name}).scalar() == 0
