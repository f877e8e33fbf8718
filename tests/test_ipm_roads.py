"""The vehicle's own drives: ``ugvmap ingest ipm`` keeps the drive's trajectory with the
layer, and ``ugvmap ingest roads`` on that layer with defaults only uses it as the road sample
and the mosaic's coverage as the valid mask.

The drive is the synthetic bend of ``tests/test_ipm_drive.py`` (its renderer shares no code
with the pipeline): a 7 m road whose centre is a circle of 41.75 m around the drive's centre,
driven in the right lane 1.75 m inside it, seen through a 20 m window.
"""

from __future__ import annotations

import shutil
import uuid
from pathlib import Path

import numpy as np
import pytest
import shapely
from click.testing import CliRunner
from rasterio.transform import from_origin
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from testkit.raster_synth import UTM33, utm_origin, write_tif
from tests.test_ipm_drive import DRIVE, GRID_ARGS, N_FRAMES


def ingest_ipm(drive: dict[str, Path], slug: str, *extra: str, frames: Path | None = None
               ) -> str:
    result = CliRunner().invoke(main, [
        "ingest", "ipm", str(frames or drive["frames"]), "--poses", str(drive["poses"]),
        "--calib", str(drive["calib"]), "--layer", slug, *GRID_ARGS, "--workers", "2", *extra])
    assert result.exit_code == 0, result.output
    return result.output


def trajectories(slug: str) -> list:
    with session_scope() as session:
        return session.execute(text(
            "SELECT t.name, ST_AsBinary(t.geom) AS wkb, t.meta FROM layer_trajectories t "
            "JOIN layers l ON l.id = t.layer_id WHERE l.slug = :s"), {"s": slug}).all()


def segments(network: str) -> list:
    """The stored segments, densified every 0.1 m, and their attributes."""
    with session_scope() as session:
        return session.execute(text(
            "SELECT ST_AsBinary(ST_Segmentize(s.geom::geography, 0.1)::geometry) AS wkb, "
            "s.lanes_forward, s.lanes_backward, s.road_class, s.confidence, s.attrs "
            "FROM road_segments s JOIN networks n ON n.id = s.network_id "
            "WHERE n.name = :n"), {"n": network}).all()


def outside_coverage(slug: str, network: str, tolerance_m: float) -> int:
    """Segments not inside the layer's coverage (its sources' valid footprints) grown by
    ``tolerance_m`` ground metres (web-mercator units are 1/cos(lat) of those)."""
    with session_scope() as session:
        return session.execute(text(
            "WITH cover AS (SELECT ST_Buffer(ST_Union(f.footprint), :tol / cos(radians(:lat)))"
            " AS g FROM raster_sources f JOIN layers l ON l.id = f.layer_id WHERE l.slug = :s) "
            "SELECT count(*) FROM road_segments s JOIN networks n ON n.id = s.network_id, cover"
            " WHERE n.name = :n AND NOT ST_Covers(cover.g, ST_Transform(s.geom, 3857))"),
            {"s": slug, "n": network, "tol": tolerance_m, "lat": DRIVE.lat0}).scalar_one()


def covered_share(slug: str, network: str) -> float:
    """Share of the true road centre inside the drive's coverage within 1 m of a segment."""
    with session_scope() as session:
        cover = shapely.from_wkb(bytes(session.execute(text(
            "SELECT ST_AsBinary(ST_Transform(ST_Union(f.footprint), 4326)) FROM raster_sources f"
            " JOIN layers l ON l.id = f.layer_id WHERE l.slug = :s"), {"s": slug}).scalar()))
    lines = shapely.union_all([shapely.from_wkb(bytes(r.wkb)) for r in segments(network)])
    return DRIVE.share_found(cover, lines)


def test_the_drive_is_kept_with_the_layer(database_url: str, drive: dict[str, Path]) -> None:
    slug = f"ipm-{uuid.uuid4().hex[:8]}"
    ingest_ipm(drive, slug)
    [row] = trajectories(slug)
    assert row.name == str(drive["frames"].resolve())
    path = shapely.get_coordinates(shapely.from_wkb(bytes(row.wkb)))
    # The vehicle drove a circle of radius 40 m: every vertex on it, one per frame used.
    assert len(path) == N_FRAMES
    assert np.abs(DRIVE.from_road_centre_m(*path.T) + DRIVE.road_offset_m).max() < 0.01
    assert row.meta["frames"] == N_FRAMES
    assert row.meta["length_m"] == pytest.approx((N_FRAMES - 1) / 7.0 * DRIVE.speed_mps, rel=0.01)

    # Another part of the drive: its own trajectory row. Its one zone comes out the same file
    # as the whole drive's (a source of the layer already), so it needs --replace.
    ingest_ipm(drive, slug, "--frames", "0:20", "--replace")
    # The same drive again: refused as it is (its zones are already the layer's), and with
    # --replace its trajectory row is replaced, not added.
    with pytest.raises(AssertionError, match="--replace"):
        ingest_ipm(drive, slug)
    ingest_ipm(drive, slug, "--replace")
    rows = trajectories(slug)
    assert sorted(r.name for r in rows) == sorted([str(drive["frames"].resolve()),
                                                   f"{drive['frames'].resolve()}[0:20]"])
    assert CliRunner().invoke(main, ["layers", "delete", slug, "--yes"]).exit_code == 0
    with session_scope() as session:
        assert session.execute(text("SELECT count(*) FROM layer_trajectories t WHERE NOT "
                                    "EXISTS (SELECT 1 FROM layers l WHERE l.id = t.layer_id)")
                               ).scalar_one() == 0


def test_roads_of_a_drive_with_defaults_only(database_url: str, drive: dict[str, Path]) -> None:
    slug, network = f"ipm-{uuid.uuid4().hex[:8]}", f"drive-{uuid.uuid4().hex[:8]}"
    ingest_ipm(drive, slug)
    result = CliRunner().invoke(main, ["ingest", "roads", "--layer", slug, "--network",
                                       network])
    assert result.exit_code == 0, result.output
    assert "(spectral classifier, sample: drive trajectory)" in result.output
    rows = segments(network)
    error = np.abs(np.concatenate([DRIVE.from_road_centre_m(*shapely.get_coordinates(
        shapely.from_wkb(bytes(r.wkb))).T) for r in rows]))
    # Measured with the sub-pixel centrelines refined on the mosaic's grid: median 0.061 m,
    # p95 0.151 m, max 0.175 m, 97.5 % covered (the pixel skeleton of before: 0.12 / 0.63 /
    # 1.87 m, 91 %). The targets are 0.10 / 0.3 / 1.5 m and 90 %.
    assert np.median(error) <= 0.10 and np.percentile(error, 95) <= 0.25 and error.max() <= 0.5
    assert covered_share(slug, network) >= 0.90
    assert outside_coverage(slug, network, 0.25) == 0
    for row in rows:
        assert row.lanes_forward == row.lanes_backward
        assert 0.0 <= row.confidence <= 1.0
        assert row.attrs["classifier"] == "spectral" and row.attrs["extracted_from"] == slug


def test_a_drive_with_a_hole_is_not_bridged(database_url: str, drive: dict[str, Path],
                                            tmp_path: Path) -> None:
    """Frames 10..27 lost (20 m of driving): with a 7 m range the mosaic has a 6 m hole across
    the road, which the extraction must not cross."""
    frames = tmp_path / "frames"
    shutil.copytree(drive["frames"], frames)
    for i in range(10, 28):
        (frames / f"frame_{i:05d}.jpg").unlink()
    slug, network = f"ipm-{uuid.uuid4().hex[:8]}", f"hole-{uuid.uuid4().hex[:8]}"
    assert "18 unreadable" in ingest_ipm(drive, slug, "--range", "7", frames=frames)
    result = CliRunner().invoke(main, ["ingest", "roads", "--layer", slug, "--network",
                                       network])
    assert result.exit_code == 0, result.output
    assert outside_coverage(slug, network, 0.25) == 0
    # Where the coverage ends across the road, the line ends straight, not bent towards the
    # lane the vehicle drove in (measured 0.48 m at worst: short, strongly curved pieces).
    error = np.abs(np.concatenate([DRIVE.from_road_centre_m(*shapely.get_coordinates(
        shapely.from_wkb(bytes(r.wkb))).T) for r in segments(network)]))
    assert error.max() <= 1.0
    report = CliRunner().invoke(main, ["network", "validate", network])
    assert report.exit_code == 0 and "2 connected components" in report.output, report.output


def test_drives_that_cannot_give_roads_say_why(database_url: str, drive: dict[str, Path],
                                               tmp_path: Path) -> None:
    zones = tmp_path / "zones"
    slug = f"ipm-{uuid.uuid4().hex[:8]}"
    ingest_ipm(drive, slug, "--zones-dir", str(zones))
    runner = CliRunner()

    # The same zones through `ingest raster`: an ipm-mosaic without a drive.
    bare = f"ipm-{uuid.uuid4().hex[:8]}"
    assert runner.invoke(main, ["ingest", "raster", *map(str, sorted(zones.glob("*.tif"))),
                                "--layer", bare, "--kind", "ipm-mosaic"]).exit_code == 0
    result = runner.invoke(main, ["ingest", "roads", "--layer", bare, "--network", "never-1"])
    assert result.exit_code == 1 and "without a stored drive" in result.output

    # A trajectory 1.5 km away from the imagery (wrong poses): no road pixel with data.
    with session_scope() as session:
        session.execute(text(
            "UPDATE layer_trajectories SET geom = ST_Translate(geom, 0.02, 0) WHERE layer_id = "
            "(SELECT id FROM layers WHERE slug = :s)"), {"s": slug})
    result = runner.invoke(main, ["ingest", "roads", "--layer", slug, "--network", "never-2"])
    assert result.exit_code == 1, result.output
    assert "does not cover any road pixel of the layer that has data" in result.output
    assert "Traceback" not in result.output
    # A mosaic that is all no-data never becomes a layer, so there is nothing to extract.
    empty = write_tif(tmp_path / "empty.tif", np.zeros((3, 64, 64), np.uint8), UTM33,
                      from_origin(*utm_origin(), 0.06, 0.06), alpha=np.zeros((64, 64), np.uint8))
    result = runner.invoke(main, ["ingest", "raster", str(empty), "--layer", "never-3",
                                  "--kind", "ipm-mosaic"])
    assert result.exit_code == 1 and "no valid pixels" in result.output, result.output
    with session_scope() as session:
        assert session.execute(text("SELECT count(*) FROM networks WHERE name LIKE 'never-%'")
                               ).scalar_one() == 0
        assert session.execute(text("SELECT count(*) FROM layers WHERE slug = 'never-3'")
                               ).scalar_one() == 0
