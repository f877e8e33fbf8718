"""Importing the real OSM extracts gives the topology an independent count predicts.

The independent count parses osmium-tool's OPL text dump directly (not pyosmium, not our
reader): ways are split at nodes used more than once, at way ends and at traffic signals, and
where the extract lacks node locations. Distinct OSM nodes at identical coordinates touch, so
they count as one node (Helsinki has 11 such pairs).
"""

from __future__ import annotations

import subprocess
from collections import Counter
from pathlib import Path

import networkx as nx
import pytest
from pyproj import Geod
from sqlalchemy import text

from app.db.session import session_scope
from ingest.network import NetworkExistsError, NetworkFileError, import_network
from ingest.network.osm_tags import NOT_ROADS

GEOD = Geod(ellps="WGS84")


def _opl_tags(field: str) -> dict[str, str]:
    pairs = (item.split("=", 1) for item in field[1:].split(",") if "=" in item)
    return dict(pairs)


def independent_count(pbf: Path, tmp_path: Path) -> tuple[int, int, float]:
    """(segments, nodes, total geodesic length in m) counted from an OPL dump."""
    opl = tmp_path / f"{pbf.stem}.opl"
    subprocess.run(["osmium", "cat", str(pbf), "-f", "opl", "-o", str(opl), "-O"], check=True)
    locations: dict[str, tuple[float, float]] = {}
    signals: set[tuple[float, float]] = set()
    ways: list[list[tuple[float, float]]] = []
    for line in opl.read_text(encoding="utf-8").splitlines():
        fields = line.split(" ")
        if line.startswith("n"):
            xs = [f for f in fields if f.startswith(("x", "y"))]
            if len(xs) == 2 and len(xs[0]) > 1:
                locations[fields[0]] = (float(xs[0][1:]), float(xs[1][1:]))
            tags = _opl_tags(next(f for f in fields if f.startswith("T")))
            if tags.get("highway") == "traffic_signals" and fields[0] in locations:
                signals.add(locations[fields[0]])
        elif line.startswith("w"):
            tags = _opl_tags(next(f for f in fields if f.startswith("T")))
            if tags.get("highway") in (None, *NOT_ROADS) or tags.get("area") == "yes":
                continue
            refs = next(f for f in fields if f.startswith("N"))[1:].split(",")
            run: list[tuple[float, float]] = []
            for ref in [*refs, None]:
                if ref in locations:
                    if not run or run[-1] != locations[ref]:  # co-located consecutive nodes
                        run.append(locations[ref])
                    continue
                if len(run) > 1:
                    ways.append(run)
                run = []
    uses = Counter(ref for way in ways for ref in way)
    is_node = {w[0] for w in ways} | {w[-1] for w in ways} | \
        {r for r, n in uses.items() if n > 1} | (signals & uses.keys())
    segments: set[tuple[tuple[float, float], ...]] = set()
    for way in ways:
        start = 0
        for i in range(1, len(way)):
            if way[i] in is_node:
                piece = tuple(way[start:i + 1])
                segments.add(min(piece, piece[::-1]))
                start = i
    length = sum(GEOD.line_length(*zip(*seg, strict=True)) for seg in segments)
    nodes = {seg[0] for seg in segments} | {seg[-1] for seg in segments}
    return len(segments), len(nodes), length


def _stored(network_id: int) -> tuple[int, int, float, list[tuple[int, int]]]:
    with session_scope() as s:
        edges = [tuple(r) for r in s.execute(text(
            "SELECT source_node, target_node FROM road_segments WHERE network_id = :n"),
            {"n": network_id})]
        nodes, length = s.execute(text(
            "SELECT (SELECT count(*) FROM road_nodes WHERE network_id = :n), "
            "(SELECT sum(length_m) FROM road_segments WHERE network_id = :n)"),
            {"n": network_id}).one()
    return len(edges), nodes, length, edges


@pytest.mark.slow
@pytest.mark.parametrize("extract", ["andorra.osm.pbf", "Helsinki.osm.pbf"])
def test_osm_import_matches_independent_count(database_url: str, shared_data: Path,
                                              tmp_path: Path, extract: str) -> None:
    pbf = shared_data / "osm" / extract
    name = f"osm-{extract.split('.')[0].lower()}"
    with session_scope() as s:
        summary = import_network(s, pbf, name, replace=True)
    segments, nodes, length = independent_count(pbf, tmp_path)
    stored_segments, stored_nodes, stored_length, edges = _stored(summary.network_id)
    assert stored_segments == summary.segments == segments
    assert stored_nodes == summary.nodes == nodes
    assert stored_length == pytest.approx(length, rel=1e-6)
    graph = nx.MultiGraph(edges)
    largest = max(nx.connected_components(graph), key=len)
    covered = sum(1 for a, _ in edges if a in largest)
    # A city or country road network is one connected piece, apart from a few fragments
    # cut off by the extract boundary.
    assert covered / len(edges) > 0.9


def test_reimport_needs_replace_and_bad_input_changes_nothing(database_url: str,
                                                             tmp_path: Path) -> None:
    road = tmp_path / "road.geojson"
    road.write_text('{"type":"Feature","properties":{"name":"a"},'
                    '"geometry":{"type":"LineString","coordinates":[[0,0],[0.001,0]]}}')
    with session_scope() as s:
        first = import_network(s, road, "reimport")
    with pytest.raises(NetworkExistsError), session_scope() as s:
        import_network(s, road, "reimport")
    broken = tmp_path / "broken.geojson"
    broken.write_text('{"type":"Feature","properties":{"oneway":"sideways"},'
                      '"geometry":{"type":"LineString","coordinates":[[0,0],[1,0]]}}')
    with pytest.raises(NetworkFileError, match="oneway"), session_scope() as s:
        import_network(s, broken, "reimport", replace=True)
    with pytest.raises(ValueError, match="not valid"), session_scope() as s:
        import_network(s, road, "Robert'); DROP TABLE road_segments;--")
    assert _stored(first.network_id)[:2] == (1, 2)


def test_cli_reports_unreadable_files_in_one_line(database_url: str, tmp_path: Path) -> None:
    from click.testing import CliRunner

    from cli.main import main

    formats = ("OpenStreetMap (.osm, .osm.pbf), GeoJSON, GeoPackage or another vector format "
               "GDAL reads")
    cases = {  # file name, content, what is said (in our words, not GDAL's or libosmium's)
        "garbage.geojson": ("{not json", "not a GeoJSON file: it is not JSON (line 1, column 2)"),
        "empty.geojson": ('{"type":"FeatureCollection","features":[]}', "no road lines found"),
        "bad.osm": ("<osm version='0.6'><way id='1'></osm",
                    "not OpenStreetMap XML: it is not well-formed XML (line 1, column"),
        "bad.osm.pbf": ("hello", "not an OpenStreetMap PBF file: its blocks cannot be read"),
        "x.gpkg": ("nope", f"not a road network file: its content is in none of {formats}"),
        "notes.txt": ("a text file\n", "notes.txt: not a road network file"),
    }
    for name, (content, says) in cases.items():
        path = tmp_path / name
        path.write_text(content)
        result = CliRunner().invoke(main, ["ingest", "network", str(path), "--network", "cli"])
        assert result.exit_code == 1, (name, result.output)
        assert result.output.startswith(f"Error: {name}: ") \
            and result.output.count("\n") == 1, result.output
        assert says in result.output, result.output
        assert "DRIVER" not in result.output and "prefixing" not in result.output
    with session_scope() as s:
        assert s.execute(text("SELECT count(*) FROM networks WHERE name = 'cli'")).scalar() == 0


def test_generic_files_are_noded_and_reprojected(database_url: str, tmp_path: Path) -> None:
    """Two crossing lines (a plus sign) in UTM 32N: imported as 4 segments meeting at one
    junction, in lon/lat, with unknown properties kept in attrs."""
    import numpy as np
    import pyogrio
    import shapely
    from pyproj import Transformer

    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True)
    (x0, x1), (y0, y1) = to_utm.transform([9.0, 9.002], [50.0, 50.0])
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    lines = [shapely.LineString([(x0, y0), (x1, y1)]),
             shapely.LineString([(cx, cy - 100), (cx, cy + 100)])]
    path = tmp_path / "plus.gpkg"
    pyogrio.raw.write(path, shapely.to_wkb(np.array(lines, dtype=object)),
                      [np.array(["east", "north"], dtype=object), np.array([1, 2])],
                      fields=["name", "survey_run"], layer="roads", driver="GPKG",
                      geometry_type="LineString", crs="EPSG:32632")
    with session_scope() as s:
        summary = import_network(s, path, "plus")
        rows = s.execute(text(
            "SELECT name, attrs, ST_XMin(geom), ST_YMin(geom) FROM road_segments "
            "WHERE network_id = :n ORDER BY name, ST_XMin(geom), ST_YMin(geom)"),
            {"n": summary.network_id}).all()
        junctions = s.execute(text("SELECT count(*) FROM road_nodes WHERE network_id = :n AND "
                                   "kind = 'junction'"), {"n": summary.network_id}).scalar()
    assert (summary.segments, summary.nodes, summary.crossings_noded, junctions) == (4, 5, 1, 1)
    assert [r.name for r in rows] == ["east", "east", "north", "north"]
    assert rows[0].attrs == {"survey_run": 1}
    assert rows[0][2] == pytest.approx(9.0, abs=1e-7) and rows[0][3] == pytest.approx(50.0)
    # 200 m north-south plus 0.002 degrees of longitude at 50N (~143 m).
    assert summary.total_length_m == pytest.approx(200 + 143.1, rel=0.01)
