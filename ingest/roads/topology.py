"""Topology-aware clean-up of a road skeleton: bridge broken roads, drop isolated crumbs.

A segmentation network loses a road where a tree crown, a shadow or a car hides a few metres
of it; thresholding then cuts the centerline, and a planner sees two dead ends where there is
one road, which turns a short trip into a long detour. A real break and a real dead end look
the same in the skeleton, but not in the probability: along a hidden stretch the network is
unsure rather than sure of "no road". So a dead end is bridged when a straight line roughly
continuing its direction reaches other skeleton within ``bridge_max_m`` and the probability
along that line supports it. What is still short and unconnected after bridging is clutter (a
car park aisle, a roof edge, a field track fragment) and goes.

Near-junctions (two junction pixels a few metres apart) are merged later by the graph builder
(``GraphParams.junction_merge_m``), so nothing here snaps them.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree
from skimage.draw import line as draw_line

from ingest.roads.skeleton import PixelWalker, neighbour_count, thin, trace

LOOP_FACTOR = 3.0
"""A bridge may not land on skeleton reachable within this many ``bridge_max_m`` along the
skeleton from its dead end: such a bridge closes a small loop (a road joined to itself round a
bend) rather than a gap. Farther along the same component is allowed: that is a ring road or a
block whose corner the threshold broke."""
MAX_TRIES = 8
"""Best-scored targets whose probability support is checked per dead end; the rest are pixels
next to them on the same road, which the probability would judge alike."""
_SQRT2 = math.sqrt(2.0)


@dataclass(frozen=True)
class TopologyParams:
    """Clean-up thresholds in metres (a length of 0 switches its step off)."""

    bridge_max_m: float = 25.0
    """Longest gap bridged: a tree crown, a shadow, a short underpass."""
    bridge_max_angle_deg: float = 35.0
    """A bridge may deviate this far from the direction its dead end points in."""
    bridge_min_support: float = 0.2
    """Mean road probability required along the bridge (off the existing skeleton)."""
    direction_m: float = 10.0
    """Length of skeleton behind a dead end that gives its direction."""
    min_fragment_m: float = 40.0
    """Isolated pieces of skeleton shorter than this in total are dropped."""


def _reachable(walker: PixelWalker, start: int, steps: int) -> set[int]:
    """Flat (padded) indices reachable from ``start`` along the skeleton within ``steps``
    8-connected steps. A step may be diagonal, so this over-covers: a loop must be clearly
    longer than the limit to be allowed, never shorter."""
    seen = {start}
    frontier = deque([start])
    on, offsets = walker.on, walker.offsets
    for _ in range(steps):
        if not frontier:
            break
        nxt: deque[int] = deque()
        for i in frontier:
            for o in offsets:
                n = i + o
                if on[n] and n not in seen:
                    seen.add(n)
                    nxt.append(n)
        frontier = nxt
    return seen


def _support(prob: np.ndarray, skel: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> float:
    """Mean probability on the bridge pixels that are not skeleton already.

    Skeleton pixels (the dead end, the target, a road the line grazes) are road by
    construction; counting them would let a 3-pixel gap pass on its two confident ends alone.
    """
    gap = ~skel[rows, cols]
    return float(prob[rows[gap], cols[gap]].mean()) if gap.any() else 1.0


def _rethin(out: np.ndarray, boxes: list[tuple[int, int, int, int]]) -> None:
    """Re-thin (in place) only the windows around drawn bridges.

    Where a bridge meets the skeleton at an angle its first or last pixel can touch two
    skeleton pixels, leaving a 3-pixel triangle that reads as a junction. Thinning just these
    windows removes that without touching the rest of an already thin skeleton.
    """
    h, w = out.shape
    for r0, r1, c0, c1 in boxes:
        r0, c0 = max(r0 - 2, 0), max(c0 - 2, 0)
        r1, c1 = min(r1 + 3, h), min(c1 + 3, w)
        out[r0:r1, c0:c1] = thin(out[r0:r1, c0:c1])


def bridge_gaps(skeleton: np.ndarray, prob: np.ndarray, resolution_m: float,
                params: TopologyParams = TopologyParams(),
                valid: np.ndarray | None = None) -> np.ndarray:
    """Copy of ``skeleton`` (bool) with dead ends joined to the skeleton they point at.

    For each dead end (exactly one 8-neighbour) the direction is the vector from the pixel
    ``direction_m`` back along its branch (stopping at a junction) to the end. Targets are
    skeleton pixels within ``bridge_max_m`` inside the ``bridge_max_angle_deg`` cone round that
    direction, not reachable within ``LOOP_FACTOR x bridge_max_m`` along the skeleton (another
    component, or far along this one). They are ranked by ``distance x (1 + angle / max
    angle)``, so straight ahead beats a nearer pixel off to the side, and the best one whose
    line has mean ``prob`` >= ``bridge_min_support`` is the dead end's proposal.

    Proposals are then accepted best first. Accepting one retires every dead end whose own
    traced stretch the bridge touches, so two dead ends facing each other get one bridge, not
    two parallel ones; each dead end bridges at most once. ``prob`` (and ``valid``, False
    where the imagery has no data) must be on the skeleton's grid.

    A bridge never crosses a no-data pixel: there the network saw nothing (a black fill, an
    unseen stretch beside a drive), so whatever probability it gives is not evidence of a
    road, and a planner must not be sent across ground nobody has seen.
    """
    skel = skeleton.astype(bool)
    if prob.shape != skel.shape or (valid is not None and valid.shape != skel.shape):
        raise ValueError(f"probability/valid grids differ from skeleton {skel.shape}")
    max_px = params.bridge_max_m / resolution_m
    count = neighbour_count(skel)
    end_r, end_c = np.nonzero(skel & (count == 1))
    if max_px < 2 or len(end_r) == 0:
        return skel.copy()

    walker = PixelWalker(skel)
    junction = np.zeros_like(walker.on)
    jr, jc = np.nonzero(skel & (count >= 3))
    junction[walker.flat(jr, jc)] = True
    pts = np.column_stack(np.nonzero(skel))
    pts_flat = walker.flat(pts[:, 0], pts[:, 1])
    _, labels = cv2.connectedComponents(skel.astype(np.uint8), connectivity=8)
    pts_comp = labels[pts[:, 0], pts[:, 1]]
    ends = np.column_stack([end_r, end_c])
    around = cKDTree(pts).query_ball_point(ends, max_px, return_sorted=False)

    back = max(3, round(params.direction_m / resolution_m))
    loop_steps = math.ceil(LOOP_FACTOR * max_px)
    max_angle = math.radians(params.bridge_max_angle_deg)
    cos_max = math.cos(max_angle)
    owners: dict[int, list[int]] = {}
    proposals: list[tuple[float, int, np.ndarray, np.ndarray]] = []
    for i, (r, c) in enumerate(ends.tolist()):
        start = int(walker.flat(r, c))
        stretch, _ = trace(walker, start, junction, back)
        for p in stretch:
            owners.setdefault(p, []).append(i)
        if len(stretch) < 3:
            continue  # a hair at a junction: no direction to speak of
        fr, fc = walker.unflat(stretch[-1])
        direction = np.array([r - fr, c - fc], float)
        direction /= np.linalg.norm(direction)
        idx = np.asarray(around[i], np.intp)
        offset = pts[idx] - (r, c)
        dist = np.hypot(offset[:, 0], offset[:, 1])
        ok = dist > 1.5
        cos = np.zeros_like(dist)
        cos[ok] = (offset[ok] @ direction) / dist[ok]
        ok &= cos >= cos_max
        same = ok & (pts_comp[idx] == labels[r, c])
        if same.any():
            near = _reachable(walker, start, loop_steps)
            ok[same] = [int(f) not in near for f in pts_flat[idx[same]]]
        if not ok.any():
            continue
        idx, dist, cos = idx[ok], dist[ok], cos[ok]
        score = dist * (1 + np.arccos(np.clip(cos, -1, 1)) / max_angle)
        for k in np.argsort(score, kind="stable")[:MAX_TRIES]:
            tr, tc = pts[idx[k]]
            rows, cols = draw_line(r, c, int(tr), int(tc))
            if valid is not None and not valid[rows, cols].all():
                continue
            if _support(prob, skel, rows, cols) >= params.bridge_min_support:
                proposals.append((float(score[k]), i, rows, cols))
                break

    out = skel.copy()
    done = np.zeros(len(ends), bool)
    boxes = []
    for _, i, rows, cols in sorted(proposals, key=lambda p: (p[0], p[1])):
        if done[i]:
            continue
        out[rows, cols] = True
        boxes.append((int(rows.min()), int(rows.max()), int(cols.min()), int(cols.max())))
        done[i] = True
        for f in walker.flat(rows, cols).tolist():
            for o in (0, *walker.offsets):
                done[owners.get(f + o, [])] = True
    _rethin(out, boxes)
    return out


def _pixel_lengths(skel: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, cols, length) of every skeleton pixel's share of centerline length (pixels):
    its links to the E, S, SE and SW neighbours.

    Orthogonal links count 1 and diagonal ones sqrt(2), except a diagonal that cuts the corner
    of two orthogonal links (an L) that already count. Pixel counts underrate a diagonal road
    by 30 %, which would drop a 45 m diagonal road as a 32 m crumb.
    """
    p = np.pad(skel, 1)
    rows, cols = np.nonzero(skel)
    r, c = rows + 1, cols + 1
    east, south = p[r, c + 1], p[r + 1, c]
    south_east = p[r + 1, c + 1] & ~east & ~south
    south_west = p[r + 1, c - 1] & ~p[r, c - 1] & ~south
    length = east.astype(float) + south + _SQRT2 * (south_east.astype(float) + south_west)
    return rows, cols, length


def drop_short_fragments(skeleton: np.ndarray, resolution_m: float,
                         min_length_m: float) -> np.ndarray:
    """Copy of ``skeleton`` without 8-connected components shorter than ``min_length_m``.

    A component's length is the sum of its pixel links (see :func:`_pixel_lengths`) plus one
    pixel for the two half pixels beyond its ends. A piece that short with no connection to
    the network cannot be driven to, so it is noise even when it is real road.
    """
    skel = skeleton.astype(bool)
    if min_length_m <= 0 or not skel.any():
        return skel.copy()
    n, labels = cv2.connectedComponents(skel.astype(np.uint8), connectivity=8)
    rows, cols, length = _pixel_lengths(skel)
    length_px = np.bincount(labels[rows, cols], weights=length, minlength=n)
    keep = (length_px + 1) * resolution_m >= min_length_m
    keep[0] = False
    return keep[labels]


def clean_topology(skeleton: np.ndarray, prob: np.ndarray, resolution_m: float,
                   params: TopologyParams = TopologyParams(),
                   valid: np.ndarray | None = None) -> np.ndarray:
    """Bridge gaps (never across no-data, ``valid`` False), then drop short fragments: in
    this order, so a piece that a bridge joined to the network counts with the network's
    length and survives."""
    bridged = bridge_gaps(skeleton, prob, resolution_m, params, valid)
    return drop_short_fragments(bridged, resolution_m, params.min_fragment_m)
