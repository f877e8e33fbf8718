"""Zebra stripes -> pedestrian crossings.

A zebra crossing is painted as wide bars along the road, side by side at a regular step
across it. Each bar alone is a wide blob (``other``: :func:`ingest.lanes.classify.classify`);
a planner needs the crossing they make together: where pedestrians cross and how wide the
crossing is. Bars are one crossing when they are parallel, each beside the next (their
middles a :data:`ZebraParams.step_m` apart across them, and not shifted along them by more
than half a bar), at least :data:`ZebraParams.min_bars` of them. Hatching (bars diagonal to
the lane lines around them, in a painted island) is not a crossing: a zebra's bars run with
the lines beside the crossing (the lines stop at it), within ``max_turn_deg``.

The crossing is a ``crosswalk`` marking: its line runs across the road through the bars'
middles, from the outer edge of the first bar to that of the last, and its ``width_m`` is the
bars' median length (how far the crossing reaches along the road), ``pieces`` its bars.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ingest.lanes.classify import Marking, axis_angle, direction_of, turn_from_lines


@dataclass(frozen=True)
class ZebraParams:
    """Thresholds in metres and degrees."""

    bar_length_m: tuple[float, float] = (1.5, 8.0)
    """How long a zebra bar is (the crossing's width along the road)."""
    bar_width_m: tuple[float, float] = (0.25, 1.0)
    step_m: tuple[float, float] = (0.6, 2.0)
    """Middle to middle of neighbouring bars (0.5 m bars with 0.5 m gaps: 1 m)."""
    max_angle_deg: float = 15.0
    """Largest angle between neighbouring bars."""
    min_bars: int = 3
    max_turn_deg: float = 30.0
    """Largest angle between the bars and the lines near them (more: hatching)."""
    near_m: float = 10.0


def crossings(bars: list[Marking], lines: list[Marking], res: float,
              params: ZebraParams = ZebraParams()) -> tuple[list[Marking], list[Marking]]:
    """(the ``crosswalk`` markings the zebra bars among ``bars`` make, the bars left over);
    ``lines`` are the image's lane lines (hatching is told from a zebra by them), ``res``
    metres per pixel."""
    candidates = [i for i, b in enumerate(bars) if b.kind == "other"
                  and params.bar_length_m[0] <= b.length_m <= params.bar_length_m[1]
                  and params.bar_width_m[0] <= b.width_m <= params.bar_width_m[1]]
    if len(candidates) < params.min_bars:
        return [], bars
    mid = np.array([shapely.get_coordinates(shapely.LineString(bars[i].coords).interpolate(
        0.5, normalized=True))[0] for i in candidates])
    way = np.array([direction_of(bars[i].coords) for i in candidates])
    rows, cols = [], []
    # Only bars whose middles are near enough to be neighbours (a mosaic holds thousands).
    reach_px = math.hypot(params.step_m[1], params.bar_length_m[1] / 2) / res
    for a, b in sorted(cKDTree(mid).query_pairs(reach_px)):
        if axis_angle(way[a], way[b]) > params.max_angle_deg:
            continue
        gap = (mid[b] - mid[a]) * res
        along = abs(float(gap @ way[a]))
        across = abs(float(gap[0] * way[a][1] - gap[1] * way[a][0]))
        half = min(bars[candidates[a]].length_m, bars[candidates[b]].length_m) / 2
        if params.step_m[0] <= across <= params.step_m[1] and along <= half:
            rows.append(a)
            cols.append(b)
    n = len(candidates)
    _, group = connected_components(coo_matrix((np.ones(len(rows)), (rows, cols)),
                                               shape=(n, n)), directed=False)
    found: list[Marking] = []
    used: set[int] = set()
    for g in np.unique(group):
        members = np.flatnonzero(group == g)
        if len(members) < params.min_bars:
            continue
        stripes = [bars[candidates[k]] for k in members]
        crossing = _crossing(stripes, mid[members], way[members], res)
        if _hatching(crossing, way[members], lines, res, params):
            continue
        found.append(crossing)
        used.update(candidates[k] for k in members)
    return found, [b for i, b in enumerate(bars) if i not in used]


def _crossing(stripes: list[Marking], mid: np.ndarray, way: np.ndarray,
              res: float) -> Marking:
    """The ``crosswalk`` marking of one zebra's bars."""
    direction = (way * np.sign(way @ way[0])[:, None]).mean(axis=0)
    direction /= max(float(np.hypot(*direction)), 1e-9)
    across = np.array([-direction[1], direction[0]])
    centre = mid.mean(axis=0)
    t = (mid - centre) @ across
    half_bar = float(np.median([s.width_m for s in stripes])) / 2 / res
    coords = np.array([centre + (t.min() - half_bar) * across,
                       centre + (t.max() + half_bar) * across])
    length_m = float(np.hypot(*(coords[1] - coords[0]))) * res
    colours = [s.colour for s in stripes]
    return Marking(coords, "crosswalk", max(set(colours), key=colours.count),
                   # a bar's traced line stops half its width short of either end
                   round(float(np.median([s.length_m + s.width_m for s in stripes])), 3),
                   round(length_m, 2),
                   round(float(np.median([s.confidence for s in stripes])), 3), len(stripes),
                   round(sum(s.width_m for s in stripes) / max(length_m, 1e-9), 3),
                   [p for s in stripes for p in s.members])


def _hatching(crossing: Marking, way: np.ndarray, lines: list[Marking], res: float,
              params: ZebraParams) -> bool:
    """Whether the lines near the bars run across them (hatching), not with them."""
    turn = turn_from_lines(way[0], shapely.LineString(crossing.coords), lines, res,
                           params.near_m)
    return turn is not None and turn > params.max_turn_deg
