"""Every extraction of a layer uses what the map team taught it: the layer's stored labels
and the review of the networks extracted from it (``ugvmap ingest roads``, the queued job),
and says how many of each it used."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import CRS, Transformer
from rasterio.transform import from_origin
from shapely.geometry import LineString, Polygon, box
from sqlalchemy import text

from app.db.session import session_scope
from app.labels import store
from cli.main import main
from ingest.queue import tasks
from ingest.roads import RoadsInputError
from ingest.roads.classify import NOT_ROAD, ROAD
from ingest.roads.georef import Image, as_image
from ingest.roads.layer import LayerSource, _area_labels
from ingest.roads.model.adapt import AdaptParams, completeness
from ingest.roads.sample import ROAD_EDGE_M, GeoSample, burn_sample
from ingest.roads.synthetic import Scene
from ingest.roads.taught import merged
from testkit.network_helpers import bearer
from tests.test_roads_adapt import CANAL, SIZE
from tests.test_roads_adapt import ROADS as CANAL_ROADS
from tests.test_roads_ingest import _layer

SLUG = "taught-scene"


def _extract(network: str, *options: str) -> str:
    result = CliRunner().invoke(main, ["ingest", "roads", "--layer", SLUG, "--network",
                                       network, "--classifier", "spectral", *options])
    assert result.exit_code == 0, result.output
    return result.output


def test_ingest_roads_uses_the_layers_labels_and_its_review(client, tmp_path: Path) -> None:
    to_lonlat = _layer(tmp_path, SLUG)  # a cross with a T arm, 400 x 300 px at 0.5 m
    with session_scope() as session:
        store.add_labels(session, SLUG, store.parse_labels({
            "type": "FeatureCollection", "features": [
                {"type": "Feature", "properties": {"label": "road"}, "geometry": {
                    "type": "LineString",
                    "coordinates": [to_lonlat(100, 150.5), to_lonlat(140, 150.5)]}},
                {"type": "Feature", "properties": {"label": "not_road"}, "geometry": {
                    "type": "Polygon", "coordinates": [[to_lonlat(*p) for p in (
                        (250, 40), (330, 40), (330, 100), (250, 100), (250, 40))]]}}]}),
            "test")
    # No --train-*: the layer's labels are the sample a per-job classifier needs.
    first = _extract("taught-a")
    assert f"extracted from layer {SLUG} (spectral classifier, sample: layer labels)" in first
    assert f"sample: 2 labels of layer {SLUG} (1 road line, 1 not-road area)" in first
    assert "review" not in first  # nothing reviewed yet

    items = "/collections/taught-a-segments/items"
    features = client.get(items).json()["features"]
    editor = bearer("editor")
    assert client.delete(f"{items}/{features[0]['id']}", headers=editor).status_code == 204
    assert client.patch(f"{items}/{features[1]['id']}", json={"road_class": "service"},
                        headers=editor).status_code == 200

    second = _extract("taught-b")
    assert "sample: layer labels + review labels)" in second
    assert (f"sample: 2 labels of layer {SLUG} (1 road line, 1 not-road area); 2 review "
            "labels from network taught-a (1 deleted, 1 confirmed)") in second
    without_review = _extract("taught-c", "--no-review-labels")
    assert "sample: layer labels)" in without_review and "review" not in without_review
    only_review = _extract("taught-d", "--no-labels")
    assert "sample: review labels)" in only_review
    assert ("sample: 2 review labels from networks taught-a, taught-b, taught-c (1 deleted, "
            "1 confirmed)") in only_review
    neither = CliRunner().invoke(main, [
        "ingest", "roads", "--layer", SLUG, "--network", "taught-e", "--classifier",
        "spectral", "--no-labels", "--no-review-labels"])
    assert neither.exit_code == 1 and "needs a training sample" in neither.output

    queued = CliRunner().invoke(main, ["ingest", "roads", "--layer", SLUG, "--network",
                                       "taught-f", "--classifier", "spectral",
                                       "--no-review-labels", "--queue"])
    assert queued.exit_code == 0, queued.output
    job_id = int(queued.output.split()[2])
    tasks.run_job(job_id)
    with session_scope() as session:
        status, message = session.execute(text(
            "SELECT status, message FROM ingest_jobs WHERE id = :id"), {"id": job_id}).one()
    assert status == "succeeded", message
    assert f"sample: 2 labels of layer {SLUG} (1 road line" in message
    assert "review" not in message

    # Re-extracting the reviewed network in place rewrites its segments and their history,
    # but not what the reviewers deleted: the next extraction still learns from it.
    _extract("taught-a", "--replace")
    again = _extract("taught-g")
    assert "1 review label from networks taught-a, " in again and "(1 deleted)" in again


def test_a_false_road_a_reviewer_deleted_stays_out_of_the_re_extraction(client,
                                                                        tmp_path: Path) -> None:
    """The issue's loop through the database: zero-shot draws a canal; a reviewer deletes
    it in the network (HTTP API); re-extracting the layer in place, without being told,
    learns from the deletion and draws no canal."""
    slug, network = "canal-scene", "canal-roads"
    to_lonlat = _layer(tmp_path, slug, Scene((SIZE, SIZE), roads=CANAL_ROADS, road_width_px=8,
                                             seed=1, decoys=[CANAL], decoy_rgb=(80, 95, 115)),
                       res=1.0)
    canal = "ST_Buffer(ST_GeogFromText(:canal), 6)::geometry"
    params = {"canal": "LINESTRING({} {}, {} {})".format(*to_lonlat(*CANAL[0]),
                                                         *to_lonlat(*CANAL[1]))}

    def along_canal() -> list[tuple[int, float, float]]:
        """(id, metres along the canal, length) of each segment meeting it."""
        with session_scope() as session:
            return [tuple(r) for r in session.execute(text(
                f"SELECT s.id, ST_Length(ST_Intersection(s.geom, {canal})::geography), "
                "s.length_m FROM road_segments s JOIN networks n ON n.id = s.network_id "
                f"WHERE n.name = :n AND ST_Intersects(s.geom, {canal})"),
                {**params, "n": network})]

    runner = CliRunner()
    zero = runner.invoke(main, ["ingest", "roads", "--layer", slug, "--network", network])
    assert zero.exit_code == 0 and "sample: none" in zero.output, zero.output
    drawn = along_canal()
    assert sum(m for _, m, _ in drawn) > 100, drawn  # the premise: zero-shot draws the canal
    editor = bearer("editor")
    items = f"/collections/{network}-segments/items"
    false = [fid for fid, metres, length in drawn if metres > length / 2]
    for fid in false:
        assert client.delete(f"{items}/{fid}", headers=editor).status_code == 204

    again = runner.invoke(main, ["ingest", "roads", "--layer", slug, "--network", network,
                                 "--replace"])
    assert again.exit_code == 0, again.output
    assert "(model classifier" not in again.output  # adapted, to the review
    assert "sample used: on the held-out half of the labels" in again.output, again.output
    assert (f"sample: {len(false)} review label{'s' if len(false) > 1 else ''} from network "
            f"{network} ({len(false)} deleted)") in again.output
    assert sum(m for _, m, _ in along_canal()) <= 25  # where the roads cross it, at most


def _image() -> Image:
    """A 100 x 100 px web-mercator image at 1 m/px near (0, 0), all valid."""
    return as_image(np.full((3, 100, 100), 120, np.uint8), np.ones((100, 100), bool),
                    from_origin(0, 100, 1, 1), CRS.from_epsg(3857), 1.0)


def test_not_road_labels_alone_reach_the_road_model_only() -> None:
    """A reviewer's deleted false roads with no road label: the road model gets them to
    adapt to; a per-job classifier, which has no road to learn, is refused in words."""
    degrees = 1 / 111_320  # about a metre at the equator
    area = Polygon([(10 * degrees, 10 * degrees), (40 * degrees, 10 * degrees),
                    (40 * degrees, 40 * degrees), (10 * degrees, 40 * degrees)])
    sample = GeoSample(not_road_areas=[area])
    source = [LayerSource("only", "only.tif")]
    for classifier in ("auto", "model", "adapted"):
        labels = _area_labels(_image(), sample, source, 1, classifier, required=False)
        assert labels is not None and (labels == NOT_ROAD).any() and not (labels == ROAD).any()
    with pytest.raises(RoadsInputError, match="the spectral classifier needs road"):
        _area_labels(_image(), sample, source, 1, "spectral", required=False)
    # Labels off this image (another area of the layer): zero-shot there.
    far = GeoSample(not_road_areas=[box(1, 1, 1.001, 1.001)])
    assert _area_labels(_image(), far, source, 2, "auto", required=False) is None


def test_a_boxed_area_with_its_roads_drawn_is_a_complete_sample() -> None:
    """A person who boxes an area "not road" and draws every road in it has labelled the area
    completely: the lines' bands are road, the box elsewhere not road, and the roads' edges
    (within ``ROAD_EDGE_M`` of a line) say nothing rather than "not road"; the adaptation
    reads it as a complete sample (anchors step aside, the encoder's context is used)."""
    crs = CRS.from_epsg(32633)
    to_map = from_origin(500_000, 5_000_100, 0.5, 0.5)  # 0.5 m pixels, 100 m across
    lonlat = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)

    def geo(*xy: tuple[float, float]) -> list[tuple[float, float]]:
        return [lonlat.transform(500_000 + x, 5_000_100 - y) for x, y in xy]

    (w, s), (e, n) = geo((0, 100), (100, 0))
    road = LineString(geo((50, 0), (50, 100)))  # a north-south road at x = 50 m
    sample = GeoSample(road_lines=[road], not_road_boxes=[(w, s, e, n)], line_width_m=3.0)
    labels = burn_sample((200, 200), to_map, crs, sample)
    row = labels[100]  # across the road, one pixel per 0.5 m
    assert row[100] == ROAD and row[100 + 2] == ROAD  # the band: 1.5 m each side
    assert (row[100 + 4:100 + 2 * int(ROAD_EDGE_M) - 1] == 0).all()  # its edges: unsaid
    assert row[100 + 2 * int(ROAD_EDGE_M) + 2] == NOT_ROAD and row[10] == NOT_ROAD
    assert completeness(labels, AdaptParams(), 0.5) > 0.9
    # The same box without its road holds one class: no complete sample of how roads look.
    box_only = burn_sample((200, 200), to_map, crs, GeoSample(not_road_boxes=[(w, s, e, n)]))
    assert completeness(box_only, AdaptParams(), 0.5) == 0.0


def test_merged_keeps_how_the_first_sample_reads_its_lines() -> None:
    drive = GeoSample(road_lines=[LineString([(0, 0), (1, 0)])], line_width_m=3.0,
                      not_road_beyond_m=9.0, open_ends=True)
    taught = GeoSample(road_lines=[LineString([(0, 1), (1, 1)])],
                       not_road_lines=[LineString([(0, 2), (1, 2)])],
                       not_road_boxes=[(0, 0, 1, 1)])
    both = merged(drive, None, taught)
    assert both is not None
    assert (both.line_width_m, both.not_road_beyond_m, both.open_ends) == (3.0, 9.0, True)
    assert len(both.road_lines) == 2 and len(both.not_road_lines) == 1
    assert list(both.not_road_boxes) == [(0, 0, 1, 1)]
    assert merged(None, GeoSample()) is None
    assert merged(None, taught) == taught
