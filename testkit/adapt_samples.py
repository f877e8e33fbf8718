"""The three kinds of sample a map team gives, drawn from an image's own truth.

``bench/roads_adapt.py`` measures adaptation with each (issue 32):

- **quadrant**: one fully labelled quadrant (the one with the most road), as
  :func:`testkit.roads_accuracy.quadrant_labels` makes it;
- **boxed**: the same quadrant labelled as a person does it completely: boxed "not road",
  every true road in it drawn as a line;
- **person**: what a person draws in about two minutes: the 5 longest roads of the truth as
  lines along their centrelines, and 3 boxes of 40 m with no road in them, put where the
  zero-shot result draws the most false road (a person boxes the mistakes they see);
- **review**: what a review of the zero-shot result leaves: its segments more than 5 m from
  every true road deleted (a not-road line each), and the true roads it missed drawn in one
  quadrant (the one where it missed the most).

Each comes with the region that is *not* scored: the labelled boxes, and 6 m around every
labelled line, so a sample is never scored on what it gave away. Everything is on the
image's pixel grid, lines in pixel-corner coordinates, as the truth's.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import shapely
from shapely.geometry import LineString, box

from ingest.roads.classify import NOT_ROAD, ROAD
from ingest.roads.curve import arc_length
from ingest.roads.sample import ROAD_EDGE_M
from testkit.roads_accuracy import Truth

LINE_HALF_WIDTH_M = 1.5
"""A drawn line labels a 3 m band: the middle of any road, whatever its width."""
UNSCORED_M = 6.0
"""Centreline pixels this close to a labelled line are not scored."""


@dataclass(frozen=True)
class AdaptSample:
    """Labels (255 road / 128 not road / 0), where scores are not counted, and what was
    drawn (the bench prints it: a sample that came out empty must show)."""

    labels: np.ndarray
    unscored: np.ndarray
    description: str


def _burn(lines: Sequence[np.ndarray], half_width_px: float, value: int, out: np.ndarray
          ) -> np.ndarray:
    """Polylines (pixel-corner coordinates) drawn ``2 x half_width_px`` thick into ``out``."""
    pts = [np.round((np.asarray(line, float) - 0.5) * 16).astype(np.int32)
           for line in lines if len(line) >= 2]
    if pts:
        cv2.polylines(out, pts, False, int(value),
                      thickness=max(1, round(2 * half_width_px)), lineType=cv2.LINE_8, shift=4)
    return out


def _near(shape: tuple[int, int], lines: Sequence[np.ndarray], half_width_px: float
          ) -> np.ndarray:
    return _burn(lines, half_width_px, 1, np.zeros(shape, np.uint8)).astype(bool)


def _metres_to(mask: np.ndarray, resolution_m: float) -> np.ndarray:
    """Every pixel's distance to the nearest True pixel of ``mask``, in metres."""
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5) * resolution_m


def _points(line: np.ndarray | LineString, step_px: float) -> np.ndarray:
    """Points every ``step_px`` along a polyline, ends included."""
    ls = line if isinstance(line, LineString) else LineString(line)
    n = max(2, int(ls.length / step_px) + 1)
    return shapely.get_coordinates(shapely.line_interpolate_point(
        ls, np.linspace(0, 1, n), normalized=True))


def _at(grid: np.ndarray, xy: np.ndarray) -> np.ndarray:
    rows = np.clip(xy[:, 1].astype(int), 0, grid.shape[0] - 1)
    cols = np.clip(xy[:, 0].astype(int), 0, grid.shape[1] - 1)
    return grid[rows, cols]


def quadrant_sample(truth: Truth) -> AdaptSample:
    """(a) The labelled quadrant of :func:`testkit.roads_accuracy.load_sample`."""
    return AdaptSample(truth.labels, truth.region,
                       "one fully labelled quadrant")


def boxed_sample(truth: Truth) -> AdaptSample:
    """(a') The same quadrant as a person labels it completely in the Teach tool: boxed "not
    road", every true road in it drawn as a line (a 3 m band), and nothing said within
    ``ROAD_EDGE_M`` of a line (:func:`ingest.roads.sample.burn_sample`'s rule for the roads'
    edges)."""
    res = truth.resolution_m
    labels = np.where(truth.region, NOT_ROAD, 0).astype(np.uint8)
    labels[_near(labels.shape, truth.lines, ROAD_EDGE_M / res) & truth.region] = 0
    labels[_near(labels.shape, truth.lines, LINE_HALF_WIDTH_M / res) & truth.region] = ROAD
    return AdaptSample(labels, truth.region, "the quadrant boxed, its roads drawn as lines")


def person_sample(truth: Truth, zero_shot_lines: Sequence[np.ndarray], lines: int = 5,
                  boxes: int = 3, box_m: float = 40.0) -> AdaptSample:
    """(b) The longest true roads as lines, and not-road boxes over zero-shot false roads."""
    shape, res = truth.road.shape, truth.resolution_m
    longest = sorted(truth.lines, key=lambda line: arc_length(np.asarray(line))[-1],
                     reverse=True)[:lines]
    size = round(box_m / res)
    near_road = _metres_to(truth.road, res) <= 2.0
    drawn = _burn(zero_shot_lines, 0.5, 1, np.zeros(shape, np.uint8))
    candidates = []
    for r in range(0, shape[0] - size + 1, max(1, size // 2)):
        for c in range(0, shape[1] - size + 1, max(1, size // 2)):
            if not near_road[r:r + size, c:c + size].any():
                candidates.append((-int(drawn[r:r + size, c:c + size].sum()), r, c))
    chosen: list[tuple[int, int]] = []
    for _, r, c in sorted(candidates):
        if all(abs(r - r2) >= size or abs(c - c2) >= size for r2, c2 in chosen):
            chosen.append((r, c))
        if len(chosen) == boxes:
            break
    labels = np.zeros(shape, np.uint8)
    for r, c in chosen:
        labels[r:r + size, c:c + size] = NOT_ROAD
    _burn(longest, LINE_HALF_WIDTH_M / res, ROAD, labels)
    unscored = _near(shape, longest, UNSCORED_M / res) | (labels == NOT_ROAD)
    return AdaptSample(labels, unscored,
                       f"{len(longest)} longest roads as lines, {len(chosen)} not-road boxes "
                       f"of {box_m:g} m")


def review_sample(truth: Truth, zero_shot_lines: Sequence[np.ndarray], far_m: float = 5.0,
                  missed_m: float = 3.0, min_drawn_m: float = 10.0) -> AdaptSample:
    """(c) Zero-shot segments far from every true road deleted; missed roads drawn in the
    quadrant where most were missed."""
    shape, res = truth.road.shape, truth.resolution_m
    to_truth = _metres_to(truth.centerline, res)
    deleted = [line for line in zero_shot_lines if len(line) >= 2
               and np.median(_at(to_truth, _points(line, 1.0 / res))) > far_m]
    found = _burn(zero_shot_lines, 0.5, 1, np.zeros(shape, np.uint8)).astype(bool)
    to_found = _metres_to(found, res)
    missed = truth.centerline & (to_found > missed_m)
    h, w = shape
    quadrants = [(r, c) for r in (0, h // 2) for c in (0, w // 2)]
    r0, c0 = max(quadrants, key=lambda q: int(missed[q[0]:q[0] + h // 2,
                                                      q[1]:q[1] + w // 2].sum()))
    area = box(c0, r0, c0 + w // 2, r0 + h // 2)
    drawn: list[np.ndarray] = []
    for line in truth.lines:
        if len(line) < 2:
            continue
        inside = LineString(line).intersection(area)
        for part in getattr(inside, "geoms", [inside]):
            if not isinstance(part, LineString) or part.length * res < min_drawn_m:
                continue
            pts = _points(part, 1.0 / res)
            miss = np.append(_at(to_found, pts) > missed_m, False)
            start = None
            for i, m in enumerate(miss):
                if m and start is None:
                    start = i
                elif not m and start is not None:
                    if (i - start) * 1.0 >= min_drawn_m:
                        drawn.append(pts[start:i])
                    start = None
    labels = np.zeros(shape, np.uint8)
    _burn(deleted, LINE_HALF_WIDTH_M / res, NOT_ROAD, labels)
    _burn(drawn, LINE_HALF_WIDTH_M / res, ROAD, labels)
    unscored = _near(shape, [*deleted, *drawn], UNSCORED_M / res)
    return AdaptSample(labels, unscored,
                       f"{len(deleted)} false segments deleted, {len(drawn)} missed roads drawn")
