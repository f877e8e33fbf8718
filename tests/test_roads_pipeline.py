"""Road extraction on synthetic scenes whose roads, houses and hairs are known exactly."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

import numpy as np
import pytest
import rasterio
import rasterio.warp
from rasterio.transform import Affine
from shapely import LineString, MultiLineString, Point

from ingest.roads.classify import training_labels
from ingest.roads.georef import Image, read_image
from ingest.roads.pipeline import Extraction, ExtractParams, extract_roads
from ingest.roads.synthetic import Scene, render

RES = 0.5
CROSS_T = [[(20, 150), (380, 150)], [(200, 20), (200, 280)], [(60, 150), (60, 280)]]
RING = ((300, 235), 45)
HOUSE = (280, 30, 330, 70)
HAIRS = [[(120, 156), (120, 178)], [(250, 144), (262, 124)], [(200, 100), (215, 95)]]
ROAD_BOX = (100, 146, 140, 154)
SPECTRAL = ExtractParams(classifier="spectral")
"""These tests pin the stages after classification on the survey's colour line (exact)."""


def scene(seed: int = 1, **kw) -> Scene:
    return Scene((300, 400), roads=CROSS_T, rings=[RING], houses=[HOUSE], hairs=HAIRS,
                 seed=seed, **kw)


def drawn_centerlines() -> MultiLineString:
    """The polylines as drawn, in output (pixel-corner) coordinates."""
    lines = [LineString(np.asarray(line, float) + 0.5) for line in CROSS_T]
    (cx, cy), r = RING
    lines.append(Point(cx + 0.5, cy + 0.5).buffer(r, quad_segs=64).exterior)
    return MultiLineString(lines)


def as_image(rgb: np.ndarray, res: float = RES) -> Image:
    return Image(rgb.astype(np.float32) / 255, None, None, None, res)


def run(rgb: np.ndarray, **params) -> Extraction:
    labels = training_labels(rgb.shape[:2], [ROAD_BOX])
    return extract_roads(as_image(rgb), labels, replace(SPECTRAL, **params))


@pytest.fixture(scope="module")
def extraction() -> Extraction:
    return run(render(scene())[0])


def test_topology_of_cross_t_and_loop(extraction: Extraction) -> None:
    g = extraction.graph
    degrees = Counter(n.degree for n in g.nodes)
    # cross: one degree-4 node; T: one degree-3 node; 5 free road ends; the ring: one node
    # whose only edge is a loop (degree 2).
    assert degrees == {4: 1, 3: 1, 1: 5, 2: 1}
    assert len(g.edges) == 7
    assert sum(e.source == e.target for e in g.edges) == 1
    assert {n.id for n in g.nodes if n.is_junction} == {
        n.id for n in g.nodes if n.degree >= 3}


def test_junctions_where_drawn(extraction: Extraction) -> None:
    junctions = sorted(n.xy for n in extraction.graph.nodes if n.is_junction)
    assert np.allclose(junctions, [(60.5, 150.5), (200.5, 150.5)], atol=1.5)


def test_centerlines_within_1_5_px_of_the_drawn_lines(extraction: Extraction) -> None:
    truth = drawn_centerlines()
    for edge in extraction.graph.edges:
        dense = LineString(edge.coords).segmentize(0.5)
        worst = max(truth.distance(Point(p)) for p in dense.coords)
        assert worst <= 1.5, (edge, worst)


def test_everything_drawn_is_found(extraction: Extraction) -> None:
    found = MultiLineString([LineString(e.coords) for e in extraction.graph.edges])
    truth = drawn_centerlines()
    # every drawn line is covered except the few pixels thinning eats at free road ends
    missed = truth.difference(found.buffer(1.5)).length
    assert missed <= 5 * 6, missed


def test_house_of_road_colour_is_removed(extraction: Extraction) -> None:
    binary = extraction.stages["binary"]
    x0, y0, x1, y1 = HOUSE
    assert binary[y0 + 5:y1 - 5, x0 + 5:x1 - 5].mean() > 0.9  # the roof does look like road
    assert not extraction.stages["houses_removed"][y0:y1, x0:x1].any()
    house = LineString([(x0, y0), (x1, y1)]).envelope
    assert all(not house.intersects(LineString(e.coords)) for e in extraction.graph.edges)


def test_hairline_spurs_are_gone(extraction: Extraction) -> None:
    ends = [Point(n.xy) for n in extraction.graph.nodes if n.degree == 1]
    for hair in HAIRS:
        tip = Point(np.asarray(hair[-1], float) + 0.5)
        assert min(tip.distance(e) for e in ends) > 10
    assert all(e.length_m > 10 for e in extraction.graph.edges)


def test_spurs_from_a_bumpy_outline_are_pruned() -> None:
    """Bumps on a road's edge make skeleton hairs; pruning leaves the single line."""
    rgb, _ = render(Scene((120, 300), roads=[[(10, 60), (290, 60)]], road_width_px=14,
                          houses=[(80, 50, 86, 76), (150, 44, 158, 74), (220, 52, 225, 72)],
                          seed=3))
    labels = training_labels(rgb.shape[:2], [(100, 56, 140, 64)])
    result = extract_roads(as_image(rgb), labels, replace(SPECTRAL, spur_max_m=10.0))
    assert len(result.graph.edges) == 1
    unpruned = extract_roads(as_image(rgb), labels, replace(SPECTRAL, spur_max_m=0.5))
    assert len(unpruned.graph.edges) > 1


def test_edge_attributes_from_the_image(extraction: Extraction) -> None:
    straight = [e for e in extraction.graph.edges if e.source != e.target]
    for e in straight:
        assert 5.0 <= e.width_m <= 7.5  # drawn 12 px = 6 m wide
        assert e.lanes == 2
        assert e.length_m == pytest.approx(LineString(e.coords).length * RES, rel=0.05)


def test_wider_roads_get_more_lanes() -> None:
    rgb, _ = render(Scene((200, 300), roads=[[(10, 100), (290, 100)]], road_width_px=30))
    labels = training_labels(rgb.shape[:2], [(100, 95, 140, 105)])
    edge = extract_roads(as_image(rgb), labels, SPECTRAL).graph.edges[0]
    assert 13.5 <= edge.width_m <= 17.0
    assert edge.lanes == 4


def test_noise_does_not_change_the_topology() -> None:
    for seed in (2, 5):
        result = run(render(scene(seed=seed, noise=10.0))[0])
        assert Counter(n.degree for n in result.graph.nodes) == {4: 1, 3: 1, 1: 5, 2: 1}


def test_learned_classifier_extracts_the_same_graph() -> None:
    rgb, road = render(scene())
    labels = np.where(road, 255, 128).astype(np.uint8)
    labels[:, 200:] = 0  # train on the left half only
    result = extract_roads(as_image(rgb), labels, ExtractParams(classifier="learned"))
    assert result.classifier == "learned"
    degrees = Counter(n.degree for n in result.graph.nodes)
    assert degrees[4] == 1 and degrees[3] == 1


def test_georeferenced_image_gives_map_coordinates(tmp_path) -> None:
    rgb, _ = render(scene())
    path = tmp_path / "ortho.tif"
    origin = (500_000.0, 4_600_000.0)
    transform = Affine.translation(*origin) @ Affine.scale(RES, -RES)
    with rasterio.open(path, "w", driver="GTiff", width=400, height=300, count=3,
                       dtype="uint8", crs="EPSG:32633", transform=transform) as dst:
        dst.write(np.moveaxis(rgb, -1, 0))
    image = read_image(path)
    # On the central meridian a UTM metre is 0.9996 ground metres.
    assert image.resolution_m == pytest.approx(RES / 0.9996, rel=1e-5)
    labels = training_labels(rgb.shape[:2], [ROAD_BOX])
    doc = extract_roads(image, labels, SPECTRAL).geojson()
    assert doc["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32633"
    cross = next(f for f in doc["nodes"] if f["properties"]["degree"] == 4)
    x, y = cross["geometry"]["coordinates"]
    assert x == pytest.approx(origin[0] + 200.5 * RES, abs=1.0)
    assert y == pytest.approx(origin[1] - 150.5 * RES, abs=1.0)
    edge = doc["features"][0]
    assert edge["properties"]["length_m"] == pytest.approx(
        LineString(edge["geometry"]["coordinates"]).length, rel=0.05)


def test_web_mercator_resolution_is_ground_metres(tmp_path) -> None:
    """Stored layers are EPSG:3857, whose unit is cos(lat) ground metres (0.5 at 60 N)."""
    path = tmp_path / "merc.tif"
    x, y = rasterio.warp.transform("EPSG:4326", "EPSG:3857", [24.94], [60.0])
    transform = Affine.translation(x[0], y[0]) @ Affine.scale(1.0, -1.0)
    with rasterio.open(path, "w", driver="GTiff", width=32, height=32, count=1, dtype="uint8",
                       crs="EPSG:3857", transform=transform) as dst:
        dst.write(np.zeros((1, 32, 32), np.uint8))
    assert read_image(path).resolution_m == pytest.approx(0.5, rel=0.01)


def test_geographic_resolution_is_in_metres(tmp_path) -> None:
    path = tmp_path / "ll.tif"
    transform = Affine.translation(-115.17, 36.24) @ Affine.scale(3e-6, -3e-6)
    with rasterio.open(path, "w", driver="GTiff", width=32, height=32, count=1, dtype="uint8",
                       crs="EPSG:4326", transform=transform) as dst:
        dst.write(np.zeros((1, 32, 32), np.uint8))
    # 3e-6 deg: 0.27 m east-west x 0.33 m north-south at 36 deg N
    assert read_image(path).resolution_m == pytest.approx(np.sqrt(0.2697 * 0.3329), rel=0.01)


def test_fine_images_run_on_a_coarser_grid_in_source_pixels() -> None:
    big = Scene((600, 800), roads=[[(x * 2, y * 2) for x, y in line] for line in CROSS_T],
                road_width_px=24, seed=4)
    rgb, _ = render(big)
    labels = training_labels(rgb.shape[:2], [(200, 292, 280, 308)])
    result = extract_roads(as_image(rgb, 0.25), labels,
                           replace(SPECTRAL, work_resolution_m=0.5))
    assert result.stages["binary"].shape == (300, 400)
    doc = result.geojson()
    assert doc["crs"] is None and doc["coordinate_space"] == "pixel"
    cross = next(f for f in doc["nodes"] if f["properties"]["degree"] == 4)
    assert np.allclose(cross["geometry"]["coordinates"], (401, 301), atol=3)
