"""Export/import round trips are lossless: geometry (exact coordinates, direction) and every
attribute of every segment and node, for GeoJSON, GeoPackage and OSM."""

from __future__ import annotations

import uuid
from dataclasses import asdict
from pathlib import Path

import pytest
from click.testing import CliRunner

from app.db.session import session_scope
from cli.main import main
from ingest.network import NodePoint, RoadAttributes, RoadLine, import_network, write_network
from ingest.network.exporter import load_network

FORMATS = [("geojson", "x.geojson"), ("gpkg", "x.gpkg"), ("osm", "x.osm.pbf"),
           ("osm", "x.osm")]


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
    """Every attribute type, nulls, unicode, a one-way, a bridge crossing without a junction,
    a loop and a traffic light. OSM stores 1e-7 degree fixed point and tags are strings, so the
    OSM variant has 7-decimal coordinates and string attrs."""
    name = f"varied-{uuid.uuid4().hex[:8]}"
    attrs = {"bridge": "yes", "layer": "1"} if osm_safe else {"bridge": True, "n": [1, {"a": 2}]}
    fine = 24.9012346 if osm_safe else 24.9012345678901
    lines = [
        RoadLine([(24.9, 60.1), (fine, 60.1), (24.9024, 60.1001)],
                 RoadAttributes(3, 0, 60.0, "forward", "primary", False, "Mannerheimintie ä'\"",
                                "asphalt", 12.5, "w1", {"ref": "1"})),
        RoadLine([(24.9024, 60.1001), (24.903, 60.1005), (24.9024, 60.101), (24.9024, 60.1001)],
                 RoadAttributes(1, 1, None, "none", "residential", True, None, None, None, None,
                                {})),
        RoadLine([(24.9012, 60.0995), (24.9012, 60.1005)],  # crosses the first: a bridge
                 RoadAttributes(0, 2, 30.5, "backward", "secondary", False, "Silta", None, None,
                                "w3", attrs)),
    ]
    with session_scope() as s:
        write_network(s, name, lines, node_crossings=False,
                      node_points=[NodePoint((24.9024, 60.1001), True, "n42")])
    return name


@pytest.mark.parametrize(("fmt", "filename"), FORMATS)
def test_round_trip_is_lossless(database_url: str, tmp_path: Path, fmt: str,
                                filename: str) -> None:
    original = varied_network(osm_safe=fmt == "osm")
    out = tmp_path / filename
    runner = CliRunner()
    result = runner.invoke(main, ["export", "network", original, "--format", fmt,
                                  "--out", str(out)])
    assert result.exit_code == 0, result.output
    copy = f"{original}-copy"
    result = runner.invoke(main, ["ingest", "network", str(out), "--network", copy])
    assert result.exit_code == 0, result.output
    assert snapshot(copy) == snapshot(original)
    before = snapshot(original)
    assert (len(before[0]), len(before[1]), sum(n[2] for n in before[1])) == (3, 4, 1)


@pytest.mark.slow
@pytest.mark.parametrize(("fmt", "filename"), [("gpkg", "h.gpkg"), ("osm", "h.osm.pbf")])
def test_real_network_round_trip(database_url: str, shared_data: Path, tmp_path: Path,
                                 fmt: str, filename: str) -> None:
    name = f"hel-{uuid.uuid4().hex[:6]}"
    with session_scope() as s:
        import_network(s, shared_data / "osm" / "Helsinki.osm.pbf", name)
    out = tmp_path / filename
    runner = CliRunner()
    assert runner.invoke(main, ["export", "network", name, "--format", fmt,
                                "--out", str(out)]).exit_code == 0
    assert runner.invoke(main, ["ingest", "network", str(out), "--network",
                                f"{name}-copy"]).exit_code == 0
    assert snapshot(f"{name}-copy") == snapshot(name)


def test_export_errors_are_one_line(database_url: str, tmp_path: Path) -> None:
    result = CliRunner().invoke(main, ["export", "network", "missing", "--format", "geojson",
                                       "--out", str(tmp_path / "x.geojson")])
    assert result.exit_code == 1 and "does not exist" in result.output
    assert not (tmp_path / "x.geojson").exists()
