"""Centreline geometry and topology of extracted roads (issue 20), on synthetic scenes whose
centrelines are known exactly: sub-pixel accuracy, smoothness, junctions where the roads
cross, no bridge across no-data, and the bad inputs a user can give."""

from __future__ import annotations

import math
from collections import Counter

import cv2
import numpy as np
import pytest

from ingest.roads import RoadsInputError
from ingest.roads.classify import fit_spectral_line, training_labels
from ingest.roads.curve import arc_length, simplify_smooth
from ingest.roads.evaluate import rasterize_lines, turn_share
from ingest.roads.finegrid import (
    BLOCK_PX,
    _distance_to_lines,
    band_blocks,
    colour_field,
)
from ingest.roads.geometry import clip_to_data
from ingest.roads.georef import Image
from ingest.roads.graph import GraphParams
from ingest.roads.pipeline import Extraction, ExtractParams, extract_roads
from ingest.roads.synthetic import GRASS_RGB, ROAD_RGB, ipm_scene
from ingest.roads.topology import bridge_gaps

RES = 0.5
SPECTRAL = ExtractParams(classifier="spectral")


def render_soft(shape: tuple[int, int], distance, width: float, seed: int = 0,
                supersample: int = 4) -> np.ndarray:
    """RGB float image (0..1) of a road: every pixel's colour mixes road and grass by the
    share of its sub-samples within ``width / 2`` of the centreline (``distance(x, y)``,
    pixel-corner coordinates), so the edges are anti-aliased like a camera's."""
    rows, cols = shape
    yy, xx = np.mgrid[0:rows * supersample, 0:cols * supersample]
    d = distance((xx + 0.5) / supersample, (yy + 0.5) / supersample)
    road = (d <= width / 2).astype(np.float32).reshape(rows, supersample, cols,
                                                       supersample).mean(axis=(1, 3))
    img = np.asarray(GRASS_RGB) * (1 - road[..., None]) + np.asarray(ROAD_RGB) * road[..., None]
    img += np.random.default_rng(seed).normal(0, 4, img.shape)
    return (np.clip(img, 0, 255) / 255).astype(np.float32)


def extract(rgb: np.ndarray, road_box: tuple[int, int, int, int],
            valid: np.ndarray | None = None, **graph) -> Extraction:
    labels = training_labels(rgb.shape[:2], [road_box])
    params = SPECTRAL if not graph else ExtractParams(classifier="spectral",
                                                      graph=GraphParams(**graph))
    return extract_roads(Image(rgb, valid, None, None, RES), labels, params)


def dense(coords: np.ndarray, step: float = 0.2) -> np.ndarray:
    cum = arc_length(coords)
    s = np.arange(0, cum[-1] + step / 2, step)
    return np.column_stack([np.interp(s, cum, coords[:, 0]), np.interp(s, cum, coords[:, 1])])


CX, CY, R, WIDTH = 150.3, 140.7, 80.0, 12.0


@pytest.fixture(scope="module")
def ring() -> tuple[Extraction, Extraction]:
    rgb = render_soft((300, 300), lambda x, y: np.abs(np.hypot(x - CX, y - CY) - R), WIDTH)
    box = (int(CX) - 3, int(CY + R) - 4, int(CX) + 3, int(CY + R) + 4)
    return extract(rgb, box), extract(rgb, box, geometry="pixel", simplify_m=0.5)


def test_curved_road_within_a_quarter_pixel_of_its_centreline(ring) -> None:
    ridge, pixel = ring
    (edge,) = ridge.graph.edges
    pts = dense(edge.coords)
    error = np.abs(np.hypot(pts[:, 0] - CX, pts[:, 1] - CY) - R)
    assert error.max() <= 0.25, error.max()
    # The old pixel-chain geometry is what this replaces: it is not that close.
    (old,) = pixel.graph.edges
    old_pts = dense(old.coords)
    assert np.abs(np.hypot(old_pts[:, 0] - CX, old_pts[:, 1] - CY) - R).max() > 0.5
    assert edge.width_m == pytest.approx(WIDTH * RES, abs=0.5)
    assert 0.9 <= edge.confidence <= 1.0


def test_curved_road_is_smooth_where_the_pixel_chain_stairs(ring) -> None:
    ridge, pixel = ring
    lines = [e.coords * RES for e in ridge.graph.edges]
    assert turn_share(lines, 1.0, 10.0)[0] == 0.0
    assert turn_share([e.coords * RES for e in pixel.graph.edges], 1.0, 10.0)[0] > 0.0
    # A ring's node lies on the curve and the line closes on it.
    (node,) = ridge.graph.nodes
    (edge,) = ridge.graph.edges
    assert np.allclose(edge.coords[0], edge.coords[-1])
    assert np.allclose(node.xy, edge.coords[0])


def test_single_straight_road_at_an_angle_is_one_straight_line() -> None:
    angle = math.radians(10)
    nx_, ny_ = -math.sin(angle), math.cos(angle)
    x0, y0 = 0.0, 60.3

    def distance(x, y):
        return np.abs((x - x0) * nx_ + (y - y0) * ny_)

    rgb = render_soft((140, 300), distance, 10.0)
    result = extract(rgb, (140, 84, 150, 88))
    (edge,) = result.graph.edges
    assert distance(*dense(edge.coords).T).max() <= 0.25
    assert len(edge.coords) <= 4  # a straight road needs no staircase of vertices
    assert {n.degree for n in result.graph.nodes} == {1}


def cross_and_t() -> tuple[np.ndarray, list[tuple[tuple[float, float], int]]]:
    """A cross at (100.4, 100.6) (the roads at 0° and 80°) and a T at (250.2, 100.6)."""
    a = math.radians(80)
    d_b = math.cos(a), math.sin(a)

    def distance(x, y):
        horizontal = np.abs(y - 100.6)
        slanted = np.abs((x - 100.4) * d_b[1] - (y - 100.6) * d_b[0])
        stem = np.where(y >= 100.6, np.abs(x - 250.2), np.hypot(x - 250.2, y - 100.6))
        return np.minimum(np.minimum(horizontal, slanted), stem)

    rgb = render_soft((220, 330), distance, 12.0)
    return rgb, [((100.4, 100.6), 4), ((250.2, 100.6), 3)]


def test_junctions_at_the_crossings_with_straight_approaches() -> None:
    rgb, truth = cross_and_t()
    result = extract(rgb, (160, 96, 200, 105))
    junctions = [n for n in result.graph.nodes if n.is_junction]
    assert sorted(n.degree for n in junctions) == [3, 4]
    for (x, y), degree in truth:
        node = min(junctions, key=lambda n: math.hypot(n.xy[0] - x, n.xy[1] - y))
        assert node.degree == degree
        assert math.hypot(node.xy[0] - x, node.xy[1] - y) <= 1.0, (node, x, y)
    # Every line leaves its junction straight: no kink where it meets the node.
    assert turn_share([e.coords * RES for e in result.graph.edges], 1.0, 10.0)[0] == 0.0


def test_a_wide_skewed_crossing_is_one_junction() -> None:
    a = math.radians(35)

    def distance(x, y):
        return np.minimum(np.abs(y - 150.5),
                          np.abs((x - 200.5) * math.sin(a) - (y - 150.5) * math.cos(a)))

    rgb = render_soft((300, 400), distance, 40.0)
    result = extract(rgb, (20, 140, 60, 160))
    degrees = Counter(n.degree for n in result.graph.nodes)
    assert degrees[4] == 1 and degrees[3] == 0, degrees


def test_no_bridge_across_no_data() -> None:
    skel = np.zeros((40, 120), bool)
    skel[20, 5:50] = True
    skel[20, 70:115] = True
    prob = np.full(skel.shape, 0.9, np.float32)  # a model may well "see" road on black fill
    assert bridge_gaps(skel, prob, 1.0)[20, 50:70].all()
    valid = np.ones(skel.shape, bool)
    valid[:, 55:65] = False
    out = bridge_gaps(skel, prob, 1.0, valid=valid)
    assert not out[:, 50:70].any()


def test_a_mosaic_with_holes_draws_nothing_in_them() -> None:
    rgb = render_soft((120, 300), lambda x, y: np.abs(y - 60.4), 12.0)
    valid = np.ones(rgb.shape[:2], bool)
    valid[:, 140:160] = False  # a strip the drive never saw, across the road
    valid[20:30, 40:60] = False  # and a hole off the road
    rgb[~valid] = 0
    result = extract(rgb, (20, 56, 60, 64), valid=valid)
    assert len(result.graph.edges) == 2
    for e in result.graph.edges:
        pts = dense(e.coords, 0.5)
        assert valid[pts[:, 1].astype(int), pts[:, 0].astype(int)].all()
        assert np.abs(pts[:, 1] - 60.4).max() <= 0.5


def test_free_ends_stop_at_the_coverage_junction_ends_stay() -> None:
    """A fitted dead end continued past the last pixel with data (the fine-grid refinement of
    a drive whose coverage ends across the road drew 0.8 m beyond it) is cut back to the
    coverage's edge; an end held by a junction is left where it is."""
    valid = np.zeros((40, 100), bool)
    valid[:, 20:80] = True
    line = np.column_stack([np.linspace(10.0, 90.0, 81), np.full(81, 20.5)])
    out = clip_to_data(line, valid, True, True)
    assert out[0, 0] == pytest.approx(20.0, abs=0.25) and out[-1, 0] == pytest.approx(80.0,
                                                                                     abs=0.25)
    assert out[0, 0] >= 20.0 and out[-1, 0] < 80.0
    assert np.all(out[:, 1] == 20.5) and np.all(np.diff(out[:, 0]) > 0)
    held = clip_to_data(line, valid, False, True)
    assert held[0, 0] == 10.0 and held[-1, 0] < 80.0
    assert clip_to_data(line[30:50], valid, True, True).tolist() == line[30:50].tolist()


def test_road_along_the_image_border() -> None:
    rgb = render_soft((100, 240), lambda x, y: np.abs(y - 5.0), 12.0)
    result = extract(rgb, (100, 0, 140, 8))
    assert result.graph.edges
    for e in result.graph.edges:
        assert np.abs(dense(e.coords)[:, 1] - 5.0).max() <= 2.0


def test_all_nodata_and_tiny_images_are_clear_errors() -> None:
    rgb = np.zeros((64, 64, 3), np.float32)
    with pytest.raises(RoadsInputError, match="no data"):
        extract_roads(Image(rgb, np.zeros((64, 64), bool), None, None, RES),
                      training_labels((64, 64), [(0, 0, 8, 8)]), SPECTRAL)
    with pytest.raises(RoadsInputError, match="too small"):
        extract_roads(Image(np.zeros((8, 8, 3), np.float32), None, None, None, RES),
                      training_labels((8, 8), [(0, 0, 4, 4)]), SPECTRAL)


def test_geojson_carries_width_and_confidence(ring) -> None:
    doc = ring[0].geojson()
    props = doc["features"][0]["properties"]
    assert 0.0 <= props["confidence"] <= 1.0 and props["width_m"] > 0
    assert {"degree", "is_junction"} <= set(doc["nodes"][0]["properties"])


def test_simplification_keeps_bends_smooth() -> None:
    t = np.linspace(0, math.pi / 2, 400)
    arc = np.column_stack([100 * np.cos(t), 100 * np.sin(t)])
    out = simplify_smooth(arc, 0.5, 5.0)
    d = np.diff(out, axis=0)
    heading = np.degrees(np.unwrap(np.arctan2(d[:, 1], d[:, 0])))
    assert np.abs(np.diff(heading)).max() <= 5.0 + 1e-6
    assert np.abs(np.hypot(out[:, 0], out[:, 1]) - 100).max() < 1e-9  # vertices on the curve


def test_fine_field_in_the_band_is_the_whole_mosaics() -> None:
    """The fine grid's colour field is computed only in blocks near the centrelines (a
    drive's mosaic is mostly verge and no-data): there it must be what the whole mosaic
    gives, blur and spline prefilter included, and every pixel within reach is in a block."""
    from scipy.ndimage import spline_filter

    rng = np.random.default_rng(3)
    shape = (300, 700)
    pixels = rng.random((*shape, 3)).astype(np.float32)
    valid = np.ones(shape, bool)
    valid[:, 600:] = False
    lines = [np.array([[10.0, 150.0], [690.0, 180.0]]), np.array([[350.0, 5.0], [360.0, 160.0]])]
    line = fit_spectral_line(pixels[140:160].reshape(-1, 3).astype(np.float64))
    limit = 3 * line.mean_distance
    dist = _distance_to_lines(lines, shape)
    blocks = band_blocks(dist, 40.0)
    field, coefficients = colour_field(pixels, valid, line, limit, blocks)

    whole = np.clip(1.0 - line.distance(pixels) / (2 * limit), 0.0, 1.0)
    whole = cv2.GaussianBlur(whole, (0, 0), 1.0)
    reference = spline_filter(np.where(valid, whole, 0.0), order=3, mode="nearest")
    inside = np.zeros(shape, bool)
    for br, bc in blocks:
        inside[br * BLOCK_PX:(br + 1) * BLOCK_PX, bc * BLOCK_PX:(bc + 1) * BLOCK_PX] = True
    assert 0 < inside.mean() < 1
    assert np.abs(field - whole)[inside].max() < 1e-6
    assert np.abs(coefficients - reference)[inside].max() < 1e-5
    assert not field[~inside].any() and not coefficients[~inside].any()
    near = cv2.distanceTransform((~rasterize_lines(lines, shape)).astype(np.uint8),
                                 cv2.DIST_L2, cv2.DIST_MASK_PRECISE) <= 40.0
    assert inside[near].all()


def test_ipm_drive_centreline_to_centimetres_with_defaults_only() -> None:
    """The vehicle's own drive: a 0.06 m mosaic seen only along the path, the trajectory as
    the sample (its lane, not the road's centre), no parameter changed."""
    scene = ipm_scene()
    result = extract_roads(scene.image, scene.labels)
    lines = [np.column_stack(result.frame.to_output @ (e.coords[:, 0], e.coords[:, 1]))
             for e in result.graph.edges]
    pts = np.vstack([dense(ln, 0.1) for ln in lines])
    error = scene.truth_distance(pts)
    assert np.median(error) <= 0.10 and np.percentile(error, 95) <= 0.3 and error.max() <= 1.5
    col, row = ~scene.transform @ (pts[:, 0], pts[:, 1])
    # Nothing across the part of the ring the drive never saw.
    assert scene.coverage[row.astype(int), col.astype(int)].all()
    assert len(result.graph.edges) == 1
