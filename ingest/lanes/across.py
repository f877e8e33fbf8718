"""Lanes from the paint: what a cut across the road meets, station by station.

A road's lanes are the gaps between its marking lines. At each station along a reference line
(a segment's centreline, a drive's path) the cut square to it meets the marking lines at
signed offsets; consecutive offsets are the lanes and their widths, the solid line between the
directions splits them into forward (right of the reference's direction) and backward, and the
outermost lines (road edges where painted) close the road. Each station stands on its own, so
a lane that opens or ends shows as a change along the segment, not an average.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

#: Marking kinds that bound lanes (stop lines and symbols do not).
BOUNDING = ("solid", "dashed", "road_edge")
GAP_M = 1.0
"""A straight stretch of a marking line longer than this is a join across a gap, not paint
(traced paint has a vertex every pixel)."""
BRIDGE_M = 8.0
"""Longest run of cuts across which a line met before and after it is taken to go on."""
AGREE_M = 0.25
"""...when the offsets it is met at before and after differ by at most this."""


@dataclass(frozen=True)
class Section:
    """The cut at one station: offsets (metres, + left of the reference) of the marking lines
    it meets, ordered right to left, with their kinds."""

    station_m: float
    offsets: tuple[float, ...]
    kinds: tuple[str, ...]

    def lanes(self) -> tuple[list[float], list[float]]:
        """(forward widths from the right edge inwards, backward widths from the centre
        outwards): split at the solid line nearest the reference (all forward without one)."""
        widths = list(np.diff(self.offsets))
        solids = [i for i, k in enumerate(self.kinds) if k == "solid"]
        if not solids:
            return widths, []
        split = min(solids, key=lambda i: abs(self.offsets[i]))
        return widths[:split], widths[split:]


def frame_at(reference: shapely.LineString, s: float) -> tuple[np.ndarray, np.ndarray]:
    """(point, unit vector to its left) of ``reference`` at ``s`` metres along it, the
    direction taken over a metre (a polyline's vertices do not jolt it)."""
    a = reference.interpolate(max(s - 0.5, 0.0))
    b = reference.interpolate(min(s + 0.5, reference.length))
    centre = reference.interpolate(s)
    t = np.array([b.x - a.x, b.y - a.y])
    t /= max(float(np.hypot(*t)), 1e-9)
    return np.array([centre.x, centre.y]), np.array([-t[1], t[0]])  # x east, y north


def bend_gaps(line: shapely.LineString, reference: shapely.LineString,
              gap_m: float = GAP_M, step_m: float = 0.25) -> shapely.LineString:
    """``line`` with every straight stretch longer than ``gap_m`` (a dashed line's join
    across a gap, a chord) redrawn at the offset from ``reference`` interpolated between its
    ends. On a bend a chord cuts inside the painted arc (by 0.12 m across a 6 m gap at 38 m
    radius: a lane 0.12 m off its width); the paint runs parallel to the road, so its offset
    from the road's reference across the gap is the one its ends have."""
    xy = shapely.get_coordinates(line)
    seg = np.hypot(*np.diff(xy, axis=0).T)
    if not (seg > gap_m).any():
        return line
    out = [xy[:1]]
    for i in range(len(seg)):
        if seg[i] > gap_m:
            (s0, o0), (s1, o1) = (_station_offset(reference, p) for p in xy[i:i + 2])
            length, ds = reference.length, s1 - s0
            closed = bool(reference.is_closed)
            if closed and abs(ds) > length / 2:
                ds -= math.copysign(length, ds)  # across a closed reference's start
            # Only a gap along the reference (not across it) and within it.
            if (closed or (min(s0, s1) > 0 and max(s0, s1) < length)) \
                    and 0.5 <= abs(ds) / seg[i] <= 1.5:
                w = np.linspace(0, 1, int(seg[i] / step_m) + 1)[1:-1]
                frames = [frame_at(reference, s % length) for s in s0 + w * ds]
                out.append(np.array([c + (o0 + wi * (o1 - o0)) * left
                                     for wi, (c, left) in zip(w, frames, strict=True)]
                                    ).reshape(-1, 2))
        out.append(xy[i + 1:i + 2])
    return shapely.LineString(np.vstack(out))


def _station_offset(reference: shapely.LineString, xy: np.ndarray) -> tuple[float, float]:
    """(metres along ``reference``, metres left of it) of point ``xy``."""
    s = float(reference.project(shapely.Point(xy)))
    c, left = frame_at(reference, s)
    return s, float(np.dot(xy - c, left))


def sections(reference: shapely.LineString, lines: list[tuple[shapely.LineString, str]],
             step_m: float = 0.5, reach_m: float = 15.0, merge_m: float = 0.3) -> list[Section]:
    """The cut every ``step_m`` along ``reference`` (metric coordinates), ``reach_m`` either
    side; marking lines met within ``merge_m`` of each other (the same paint found twice, in
    two overlapping tiles) count once. A dashed line's joins across its gaps follow the
    reference (:func:`bend_gaps`), not the chord."""
    bounding = [(bend_gaps(line, reference), kind) for line, kind in lines
                if kind in BOUNDING]
    if not bounding:
        return []
    geoms = np.array([line for line, _ in bounding])
    kinds = [kind for _, kind in bounding]
    tree = shapely.STRtree(geoms)
    out = []
    for s in np.arange(step_m / 2, reference.length, step_m):
        c, left = frame_at(reference, float(s))
        cut = shapely.LineString([c - reach_m * left, c + reach_m * left])
        met: list[tuple[float, str]] = []
        for i in tree.query(cut, predicate="intersects"):
            for p in shapely.get_coordinates(shapely.intersection(geoms[i], cut)):
                met.append((float(np.dot(p - c, left)), kinds[i]))
        met.sort()
        merged: list[tuple[float, str]] = []
        for offset, kind in met:
            if merged and offset - merged[-1][0] < merge_m:
                continue
            merged.append((offset, kind))
        out.append(Section(round(float(s), 3), tuple(o for o, _ in merged),
                           tuple(k for _, k in merged)))
    return _bridged(out, step_m, merge_m)


def _bridged(cuts: list[Section], step_m: float, merge_m: float,
             bridge_m: float = BRIDGE_M, agree_m: float = AGREE_M) -> list[Section]:
    """``cuts`` with a line that two cuts up to ``bridge_m`` apart meet at offsets within
    ``agree_m`` of each other added to the cuts between them that miss it (at the offset
    interpolated between the two): a stretch of line not found between two found ones (a
    far edge line broken up by blur, a dash missed) is the same line, as paint runs along the
    road. Only between two cuts that meet it: a line that ends (a lane that ends, the end of
    the imagery) is not carried on."""
    span = round(bridge_m / step_m)
    added: list[list[tuple[float, str]]] = [[] for _ in cuts]
    for i, cut in enumerate(cuts):
        for offset, kind in zip(cut.offsets, cut.kinds, strict=True):
            for j in range(i + 1, min(i + span + 1, len(cuts))):
                ahead = np.asarray(cuts[j].offsets)
                if len(ahead) and np.abs(ahead - offset).min() <= agree_m:
                    end = float(ahead[np.abs(ahead - offset).argmin()])
                    for m in range(i + 1, j):
                        at = offset + (end - offset) * (m - i) / (j - i)
                        if not any(abs(o - at) < merge_m for o in cuts[m].offsets):
                            added[m].append((at, kind))
                    break
    out = []
    for cut, extra in zip(cuts, added, strict=True):
        if not extra:
            out.append(cut)
            continue
        met = sorted([*zip(cut.offsets, cut.kinds, strict=True), *extra])
        out.append(Section(cut.station_m, tuple(round(o, 3) for o, _ in met),
                           tuple(k for _, k in met)))
    return out
