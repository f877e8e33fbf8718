"""A layer is one place: a file that touches none of it is refused unless ``--add``, every
ingest says where each source landed, and ``ugvmap layers remove-source`` takes one source
out again."""

from __future__ import annotations

import re
import uuid
from pathlib import Path

import cv2
import numpy as np
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import get_engine
from app.jobs.kinds import RasterParams
from cli.main import main
from testkit.raster_synth import synthetic_utm, utm_origin
from tests.test_raster_ingest_errors import snapshot

AUSTRIA = utm_origin(15.2, 48.3)
SICILY = utm_origin(15.0, 37.5)


def run_cli(*args: str):
    return CliRunner().invoke(main, list(args))


def _layer(slug: str) -> dict:
    with get_engine().connect() as conn:
        row = conn.execute(text(
            "SELECT version, ST_XMin(bounds) AS west, ST_YMin(bounds) AS south, (SELECT "
            "count(*) FROM raster_sources s WHERE s.layer_id = l.id) AS sources FROM layers l "
            "WHERE slug = :slug"), {"slug": slug}).one()
    return row._asdict()


def test_a_source_far_from_the_layer_is_refused_unless_added(database_url: str,
                                                             tmp_path: Path) -> None:
    slug = f"area-{uuid.uuid4().hex[:8]}"
    home, _ = synthetic_utm(tmp_path / "home.tif", 200, 200, 0.5, AUSTRIA)
    # 100 m east of home's corner: touches it along its east edge.
    beside, _ = synthetic_utm(tmp_path / "beside.tif", 200, 200, 0.5,
                              (round(AUSTRIA[0]) + 100, AUSTRIA[1]))
    far, _ = synthetic_utm(tmp_path / "far.tif", 200, 200, 0.5, SICILY)

    first = run_cli("ingest", "raster", str(home), "--layer", slug)
    assert first.exit_code == 0, first.output
    # Where it landed: the centre (lon,lat) and the ground size, on every ingest.
    assert re.search(r"home.tif: \d+x\d+ px at z\d+ \([\d.]+ m/px\), centre "
                     r"15\.20\d{3},48\.29\d{3}, 10\d x 10\d m -> ", first.output), first.output
    assert first.output.strip().endswith(f"layer {slug} at version 1")

    before = snapshot()
    refused = run_cli("ingest", "raster", str(far), "--layer", slug)
    assert refused.exit_code == 1
    assert re.search(rf"far.tif: lies at 15\.00\d+,37\.49\d+, 1,20\d km from the area of "
                     rf"layer {slug}'s sources \(15\.2\d+,48\.29\d+,15\.20\d+,48\.30\d+\), "
                     r"touching none of it; ingest it into a layer of its own \(--layer NAME\), "
                     r"or add it to this one as a separate area with --add", refused.output), \
        refused.output
    assert snapshot() == before  # nothing written, nothing registered

    touching = run_cli("ingest", "raster", str(beside), "--layer", slug)
    assert touching.exit_code == 0, touching.output
    assert touching.output.strip().endswith(
        f"layer {slug} at version 2: 2 sources (1 added)")

    added = run_cli("ingest", "raster", str(far), "--layer", slug, "--add")
    assert added.exit_code == 0, added.output
    assert "far.tif: " in added.output and ", centre 15.00" in added.output
    assert added.output.strip().endswith(
        f"layer {slug} at version 3: 3 sources (1 added), in 2 separate areas")
    assert _layer(slug)["south"] < 37.5

    far_id = next(line.split()[1].rstrip(":") for line in
                  run_cli("layers", "show", slug).output.splitlines() if "far.tif" in line)
    far_cog = Path(run_cli("layers", "show", slug).output.splitlines()[-1].split()[-1])
    assert far_cog.is_file()
    removed = run_cli("layers", "remove-source", slug, "far.tif", "--yes")
    assert removed.exit_code == 0, removed.output
    assert removed.output.strip() == (f"removed source {far_id} (far.tif) from layer {slug}: "
                                      "version 4, 2 sources")
    assert not far_cog.exists()
    after = _layer(slug)
    assert after["version"] == 4 and after["sources"] == 2 and after["south"] > 48
    assert "far.tif" not in run_cli("layers", "show", slug).output
    again = run_cli("ingest", "raster", str(home), "--layer", slug, "--replace")
    assert again.exit_code == 0, again.output
    assert again.output.strip().endswith(
        f"layer {slug} at version 5: 2 sources (1 added, 1 replaced)")


def test_a_new_layer_is_the_place_of_its_first_file(database_url: str,
                                                    tmp_path: Path) -> None:
    slug = f"area-{uuid.uuid4().hex[:8]}"
    home, _ = synthetic_utm(tmp_path / "home.tif", 100, 100, 0.5, AUSTRIA)
    far, _ = synthetic_utm(tmp_path / "far.tif", 100, 100, 0.5, SICILY)
    refused = run_cli("ingest", "raster", str(home), str(far), "--layer", slug)
    assert refused.exit_code == 1
    assert ("far.tif: lies at 15.0" in refused.output
            and f"from the area of home.tif, the first file given for the new layer {slug} "
            in refused.output), refused.output
    assert _layer_count(slug) == 0
    both = run_cli("ingest", "raster", str(home), str(far), "--layer", slug, "--add")
    assert both.exit_code == 0, both.output
    assert both.output.strip().endswith(f"layer {slug} at version 1 in 2 separate areas")
    # A queued ingest takes the same choice.
    assert RasterParams.model_validate({"sources": [str(far)], "layer": slug,
                                        "add": True}).add


def _layer_count(slug: str) -> int:
    with get_engine().connect() as conn:
        return conn.execute(text("SELECT count(*) FROM layers WHERE slug = :s"),
                            {"s": slug}).scalar_one()


def test_remove_source_refuses_what_it_cannot_do(database_url: str, tmp_path: Path) -> None:
    slug = f"area-{uuid.uuid4().hex[:8]}"
    home, _ = synthetic_utm(tmp_path / "home.tif", 100, 100, 0.5, AUSTRIA)
    assert run_cli("ingest", "raster", str(home), "--layer", slug).exit_code == 0
    before = snapshot()
    for args, says in [
        ((slug, "home.tif", "--yes"), f"home.tif is layer {slug}'s only source: delete the "
                                      f"layer with `ugvmap layers delete {slug}`"),
        ((slug, "nope.tif", "--yes"), f"layer {slug} has no source 'nope.tif' (ids and names: "
                                      f"`ugvmap layers show {slug}`)"),
        (("no-such-layer", "1", "--yes"), "no raster layer 'no-such-layer'"),
    ]:
        result = run_cli("layers", "remove-source", *args)
        assert result.exit_code == 1 and says in result.output, result.output
        assert "Traceback" not in result.output
    asked = CliRunner().invoke(main, ["layers", "remove-source", slug, "home.tif"], input="n\n")
    assert asked.exit_code == 1 and "Aborted" in asked.output
    assert snapshot() == before


def _png_with_world_file(tmp_path: Path, name: str, world: tuple[float, ...]) -> Path:
    png = tmp_path / f"{name}.png"
    rgb = np.full((64, 64, 3), 128, np.uint8)
    rgb[20:40] = 200
    cv2.imwrite(str(png), rgb)
    png.with_suffix(".pgw").write_text("\n".join(map(str, world)) + "\n")
    return png


def test_world_file_numbers_that_do_not_fit_the_crs(database_url: str, tmp_path: Path) -> None:
    east, north = AUSTRIA
    utm = _png_with_world_file(tmp_path, "utm", (0.5, 0, 0, -0.5, east, north))
    # UTM 33N numbers said to be Lambert-93 (France): a valid place, but not France.
    result = run_cli("ingest", "raster", str(utm), "--layer", f"w-{uuid.uuid4().hex[:8]}",
                     "--crs", "EPSG:2154")
    assert result.exit_code == 0, result.output
    assert re.search(r"Warning: utm.png: its world file puts it at -?[\d.]+,-?[\d.]+ "
                     r"\(lon,lat\), outside where EPSG:2154 is used \(France", result.output), \
        result.output
    assert "centre " in result.output
    # The right CRS: no warning.
    right = run_cli("ingest", "raster", str(utm), "--layer", f"w-{uuid.uuid4().hex[:8]}",
                    "--crs", "EPSG:32633")
    assert right.exit_code == 0 and "Warning" not in right.output, right.output
    assert "centre 15.20" in right.output

    before = snapshot()
    degrees = _png_with_world_file(tmp_path, "deg", (1e-5, 0, 0, -1e-5, 15.2, 48.3))
    refused = run_cli("ingest", "raster", str(degrees), "--layer", "never", "--crs",
                      "EPSG:32633")
    assert refused.exit_code == 1
    assert ("deg.png: pixel size 1e-05 m is not plausible: the world file's numbers look like "
            "degrees (origin 15.2,48.3, pixel 1e-05) but --crs EPSG:32633 is in metres; a "
            "lon/lat world file wants --crs EPSG:4326") in refused.output, refused.output
    metres = _png_with_world_file(tmp_path, "m", (0.5, 0, 0, -0.5, east, north))
    refused = run_cli("ingest", "raster", str(metres), "--layer", "never", "--crs",
                      "EPSG:4326")
    assert refused.exit_code == 1
    assert "the world file's numbers look like metres" in refused.output, refused.output
    assert snapshot() == before
