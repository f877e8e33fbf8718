"""Coordinates that cannot be lon/lat are refused at import (with a hint when they look like
metres) and reported by ``network validate``; a file of zero-length lines is an error, not an
empty network (issue 12)."""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import pytest
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from testkit.network_helpers import grid_network


def _geojson(path: Path, lines: list[list[list[float]]], crs: str | None = None) -> Path:
    doc: dict = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": f"road {i}"},
         "geometry": {"type": "LineString", "coordinates": coords}}
        for i, coords in enumerate(lines)]}
    if crs:
        doc["crs"] = {"type": "name", "properties": {"name": crs}}
    path.write_text(json.dumps(doc))
    return path


def _import(path: Path) -> tuple[int, str, str]:
    name = f"coord-{uuid.uuid4().hex[:8]}"
    result = CliRunner().invoke(main, ["ingest", "network", str(path), "--network", name])
    return result.exit_code, result.output, name


def _exists(name: str) -> bool:
    with session_scope() as s:
        return s.execute(text("SELECT count(*) FROM networks WHERE name = :n"),
                         {"n": name}).scalar_one() > 0


GOOD = [[1.50, 42.50], [1.51, 42.50]]


@pytest.mark.parametrize("bad", [[200.0, 42.5], [1.5, 95.0], [-180.5, 0.0], [0.0, -90.01]])
def test_out_of_range_degrees_are_refused(database_url: str, tmp_path: Path, bad) -> None:
    # Before: lon 200 / lat 95 were stored as they were and validate said OK.
    code, out, name = _import(_geojson(tmp_path / "r.geojson", [GOOD, [GOOD[0], bad]]))
    assert code == 1, out
    assert f"line 2 has coordinate ({bad[0]:g}, {bad[1]:g}) outside lon -180..180" in out
    assert "metres" not in out and "Traceback" not in out
    assert not _exists(name)


def test_web_mercator_metres_without_crs_get_a_hint(database_url: str, tmp_path: Path) -> None:
    metres = [[[166_979.0, 5_236_000.0], [168_000.0, 5_236_500.0]],
              [[168_000.0, 5_236_500.0], [169_000.0, 5_237_000.0]]]
    code, out, name = _import(_geojson(tmp_path / "m.geojson", metres))
    assert code == 1 and "look like projected metres" in out and '"crs" member' in out
    assert not _exists(name)
    # The same numbers with the CRS named are reprojected and imported.
    code, out, name = _import(_geojson(tmp_path / "m2.geojson", metres, crs="EPSG:3857"))
    assert code == 0, out
    assert "2 segments" in out and _exists(name)


def test_nan_coordinates_are_refused(database_url: str, tmp_path: Path) -> None:
    path = tmp_path / "nan.geojson"
    path.write_text('{"type": "LineString", "coordinates": [[1.5, 42.5], [NaN, 42.5]]}')
    code, out, name = _import(path)
    assert code == 1 and "(nan, 42.5) outside" in out and not _exists(name)


def test_only_zero_length_lines_is_an_error(database_url: str, tmp_path: Path) -> None:
    # Before: an empty network was created and the command exited 0.
    dots = [[[1.5, 42.5], [1.5, 42.5]], [[1.6, 42.6], [1.6, 42.6], [1.60000001, 42.6]]]
    code, out, name = _import(_geojson(tmp_path / "z.geojson", dots))
    assert code == 1 and "all 2 lines have zero length" in out
    assert not _exists(name)
    # One real line among them imports (the dots are dropped by noding).
    code, out, name = _import(_geojson(tmp_path / "z2.geojson", [*dots, GOOD]))
    assert code == 0 and "1 segments" in out, out


def test_validate_reports_out_of_range_coordinates(database_url: str) -> None:
    net = grid_network()
    with session_scope() as s:  # e.g. written by an older version, or by hand in psql
        s.execute(text("UPDATE road_segments SET geom = ST_Translate(geom, 190, 0) "
                       "WHERE id = (SELECT min(id) FROM road_segments WHERE network_id = :n)"),
                  {"n": net.network_id})
    result = CliRunner().invoke(main, ["network", "validate", net.network])
    assert result.exit_code == 1
    assert "ERROR coordinates outside lon -180..180, lat -90..90: 1" in result.output
