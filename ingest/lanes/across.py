"""Lanes from the paint: what a cut across the road meets, station by station.

A road's lanes are the gaps between its marking lines. At each station along a reference line
(a segment's centreline, a drive's path) the cut square to it meets the marking lines at
signed offsets; consecutive offsets are the lanes and their widths, the solid line between the
directions splits them into forward (right of the reference's direction) and backward, and the
outermost lines (road edges where painted) close the road. Each station stands on its own, so
a lane that opens or ends shows as a change along the segment, not an average.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

#: Marking kinds that bound lanes (stop lines and symbols do not).
BOUNDING = ("solid", "dashed", "road_edge")


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


def sections(reference: shapely.LineString, lines: list[tuple[shapely.LineString, str]],
             step_m: float = 0.5, reach_m: float = 15.0, merge_m: float = 0.3) -> list[Section]:
    """The cut every ``step_m`` along ``reference`` (metric coordinates), ``reach_m`` either
    side; marking lines met within ``merge_m`` of each other (the same paint found twice, in
    two overlapping tiles) count once."""
    bounding = [(line, kind) for line, kind in lines if kind in BOUNDING]
    if not bounding:
        return []
    geoms = np.array([line for line, _ in bounding])
    kinds = [kind for _, kind in bounding]
    tree = shapely.STRtree(geoms)
    out = []
    for s in np.arange(step_m / 2, reference.length, step_m):
        a = reference.interpolate(max(s - 0.5, 0.0))
        b = reference.interpolate(min(s + 0.5, reference.length))
        centre = reference.interpolate(s)
        t = np.array([b.x - a.x, b.y - a.y])
        t /= max(float(np.hypot(*t)), 1e-9)
        left = np.array([-t[1], t[0]])  # x east, y north: left of travel
        c = np.array([centre.x, centre.y])
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
    return out
