"""Single stages with known answers: colour line, house rule, cleaning, spur pruning, scores."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ingest.roads.classify import (
    NOT_ROAD,
    ROAD,
    fit_spectral_line,
    spectral_classify,
)
from ingest.roads.clean import clean_mask
from ingest.roads.evaluate import buffer_scores
from ingest.roads.houses import HouseRule, is_house_like, remove_houses
from ingest.roads.skeleton import neighbour_count, prune_spurs, thin


def test_total_least_squares_line_recovers_the_grey_axis() -> None:
    rng = np.random.default_rng(0)
    t = rng.uniform(0.2, 0.8, 2000)
    direction = np.array([1.0, 1.0, 1.1]) / np.linalg.norm([1.0, 1.0, 1.1])
    noise = rng.normal(0, 0.01, (2000, 3))
    line = fit_spectral_line(t[:, None] * direction + noise)
    assert abs(abs(line.direction @ direction) - 1) < 1e-3
    # mean distance of isotropic 2-D noise (sigma 0.01) off the line: sigma * sqrt(pi/2)
    assert line.mean_distance == pytest.approx(0.01 * np.sqrt(np.pi / 2), rel=0.1)
    flat = fit_spectral_line(np.full((50, 3), 0.5))
    assert flat.mean_distance > 0  # a single-colour sample still gives a usable tolerance


def _grey(level: float, noise: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` grey pixels around ``level``: brightness noise, a little chroma."""
    return level + rng.normal(0, noise, (n, 1)) + rng.normal(0, 1.5, (n, 3))


@pytest.mark.parametrize(("ground", "bounded"), [
    ((95, 95, 95), True),       # darker grey ground: on the asphalt's colour line
    ((150, 148, 145), True),    # a brighter grey gravel verge: on it too, beyond the road
    ((70, 125, 55), False),     # green grass: the line alone parts them, shade and all
])
def test_the_colour_line_ends_where_a_grey_background_lies_on_it(ground, bounded) -> None:
    """A drive's sample: road pixels (grey asphalt with a little white paint) and not-road
    ones. Without the background the line runs on through every grey: a 7 m road on darker
    grey ground came out as the whole 30 m wide mosaic (centreline 0.3-1.0 m off)."""
    rng = np.random.default_rng(1)
    road = np.vstack([_grey(122, 4, 3000, rng), _grey(235, 3, 60, rng)])
    other = np.asarray(ground, float) + rng.normal(0, 5, (3000, 3))
    shade = _grey(80, 3, 200, rng)  # the road in a shadow: darker along the same line
    pixels = np.vstack([road, other, shade])[:, None, :]
    labels = np.concatenate([np.full(len(road), ROAD), np.full(len(other), NOT_ROAD),
                             np.zeros(len(shade))])[:, None].astype(np.uint8)
    found = spectral_classify(pixels, labels)[:, 0]
    assert found[:len(road)].mean() >= 0.95
    ground_found = found[len(road):len(road) + len(other)].mean()
    shade_found = found[len(road) + len(other):].mean()
    if bounded:
        assert ground_found <= 0.05
    else:
        assert ground_found <= 0.01 and shade_found >= 0.95


def _blob(draw) -> np.ndarray:
    canvas = np.zeros((200, 200), np.uint8)
    draw(canvas)
    return canvas


@pytest.mark.parametrize(("draw", "house"), [
    (lambda c: cv2.rectangle(c, (50, 50), (90, 80), 1, -1), True),
    (lambda c: cv2.fillPoly(c, [cv2.boxPoints(((100, 100), (60, 30), 30)).astype(np.int32)], 1),
     True),
    (lambda c: cv2.rectangle(c, (10, 90), (190, 100), 1, -1), False),  # 18:1 strip: a road
    (lambda c: cv2.fillPoly(c, [np.array([[40, 40], [160, 40], [160, 60], [60, 60], [60, 160],
                                          [40, 160]], np.int32)], 1), False),  # L-shaped
    (lambda c: cv2.circle(c, (100, 100), 40, 1, -1), False),
])
def test_house_rule(draw, house: bool) -> None:
    mask = _blob(draw)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    assert is_house_like(contours[0]) is house
    assert remove_houses(mask.astype(bool)).any() is not house


def test_house_inside_a_block_of_roads_is_removed() -> None:
    """A roof enclosed by the four roads of its block (a blob inside another blob's hole)."""
    mask = np.zeros((200, 200), np.uint8)
    cv2.rectangle(mask, (20, 20), (180, 180), 1, 8)  # the block's roads
    cv2.rectangle(mask, (80, 80), (120, 110), 1, -1)  # the roof
    out = remove_houses(mask.astype(bool))
    assert not out[85:105, 85:115].any()
    assert out[20, 100] and out[100, 20]  # the square loop of road is not a roof


def test_house_rule_thresholds_are_parameters() -> None:
    mask = _blob(lambda c: cv2.rectangle(c, (10, 90), (190, 100), 1, -1))
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    assert is_house_like(contours[0], HouseRule(max_side_ratio=20.0))


def test_cleaning_sizes_are_in_metres() -> None:
    mask = np.zeros((200, 200), bool)
    mask[90:110, :] = True            # a 20 px road
    mask[20, 20:60] = True            # a 1 px scratch
    mask[150:154, 150:154] = True     # a 16 px speck
    mask[98:101, 100:103] = False     # a car-sized hole
    out = clean_mask(mask, resolution_m=0.5, open_m=1.0, close_m=2.0, min_area_m2=10.0,
                     max_hole_m2=4.0)
    assert out[90:110].all()
    assert not out[:80].any() and not out[120:].any()
    # the same physical sizes at 2 m/px: the 20 px road is 40 m wide, the speck stays too
    coarse = clean_mask(mask, resolution_m=2.0, open_m=1.0, close_m=2.0, min_area_m2=10.0)
    assert coarse[150:154, 150:154].all()


def test_spur_pruning_grows_and_keeps_real_ends() -> None:
    skel = np.zeros((100, 200), bool)
    skel[50, 10:190] = True           # the road
    skel[40:50, 60] = True            # a 10 px hair
    skel[20:50, 120] = True           # a 30 px side road
    pruned = prune_spurs(skel, max_length_px=15)
    assert not pruned[40:49, 60].any()
    assert pruned[21:50, 120].all()
    assert pruned[50, 12:188].all()   # free road ends are not spurs
    assert ((neighbour_count(pruned) >= 3) & pruned).sum() <= 4


def test_thinning_is_one_pixel_and_connected() -> None:
    mask = np.zeros((100, 100), np.uint8)
    cv2.line(mask, (10, 10), (90, 80), 1, 9)
    skel = thin(mask)
    assert cv2.connectedComponents(skel.astype(np.uint8), connectivity=8)[0] == 2
    assert (neighbour_count(skel)[skel] <= 2).all()


def test_buffer_scores_known_answers() -> None:
    gt = np.zeros((100, 100), bool)
    gt[50, 10:90] = True
    shifted = np.roll(gt, 2, axis=0)
    s1, s2 = buffer_scores(shifted, gt, [1, 2])
    assert (s1.precision, s1.recall, s1.quality) == (0.0, 0.0, 0.0)
    assert (s2.precision, s2.recall, s2.quality) == (1.0, 1.0, 1.0)
    half = gt.copy()
    half[50, 50:] = False
    (s,) = buffer_scores(half, gt, [1])
    assert s.precision == 1.0
    assert s.recall == pytest.approx(41 / 80)  # 40 px plus the one within 1 px of the end
    assert s.quality == pytest.approx(40 / (40 + 80 - 41))
