"""Segments near points, found in memory: what every routing service snaps with.

Why in memory: snapping by PostGIS (a KNN walk per point, then each candidate projected in
its UTM zone and measured on the spheroid) was 2-3 ms of a city route's ~9 ms, and a
1,000-point trace to match would pay it a thousand times. The graph already holds every
segment's coordinates, so an STRtree over the segments' bounding boxes finds the candidates
in microseconds, and numpy measures them all at once in each point's local metric frame
(WGS84 radii of curvature at the point: within 1e-4 of the spheroid's distance over a few
kilometres, like the UTM projection it replaces). Fractions are read off the graph's metric
vertex fractions, the ones the engine prices pieces with.

Kept current under live edits without rebuilding the tree: a graph version's index is the
tree of the version it was built on plus the ids of the segments added or changed since
(``stale``, few): tree hits of a stale id are dropped and the stale segments are tested
directly, and a deleted segment's hits find no row. Once more than :data:`STALE_MAX` (or
0.2 % of the network) have changed, the next version builds a new tree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import shapely

from app.routing.native import kernel

if TYPE_CHECKING:
    from app.routing.graph import RoadGraph

STALE_MAX = 1024
WGS84_A = 6_378_137.0
WGS84_E2 = 0.00669437999014
DEG = math.pi / 180.0


@dataclass(frozen=True)
class SegmentIndex:
    """An STRtree over the segments of the version it was built on, and what changed since."""

    tree: shapely.STRtree
    ids: np.ndarray  # segment id of each tree item
    stale: np.ndarray  # ascending ids added or changed since the tree was built

    @classmethod
    def of(cls, graph: RoadGraph) -> SegmentIndex:
        """The index of every segment of ``graph``."""
        b = graph.bbox
        return cls(shapely.STRtree(shapely.box(b[:, 0], b[:, 1], b[:, 2], b[:, 3])),
                   graph.segs.ids.copy(), np.zeros(0, np.int64))

    def after(self, changed: np.ndarray, n_rows: int) -> SegmentIndex | None:
        """This index for the next version, where the segments ``changed`` were added or
        edited; ``None`` when so many changed that a new tree pays off."""
        stale = np.union1d(self.stale, changed)
        if len(stale) > max(STALE_MAX, n_rows // 500):
            return None
        return SegmentIndex(self.tree, self.ids, stale)

    def pairs(self, graph: RoadGraph, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(box index, segment row) of every current segment whose bounding box meets one of
        ``boxes`` ((m, 4) min lon, min lat, max lon, max lat)."""
        which, item = self.tree.query(shapely.box(boxes[:, 0], boxes[:, 1], boxes[:, 2],
                                                  boxes[:, 3]))
        ids = self.ids[item]
        if len(self.stale):
            keep = ~np.isin(ids, self.stale, assume_unique=False)
            which, ids = which[keep], ids[keep]
        rows, found = _rows_of(graph, ids)
        which, rows = which[found], rows[found]
        if len(self.stale):
            stale_rows, present = _rows_of(graph, self.stale)
            stale_rows = stale_rows[present]
            b = graph.bbox[stale_rows]
            meet = ((b[None, :, 0] <= boxes[:, None, 2]) & (b[None, :, 2] >= boxes[:, None, 0])
                    & (b[None, :, 1] <= boxes[:, None, 3]) & (b[None, :, 3] >= boxes[:, None, 1]))
            extra_which, extra = np.nonzero(meet)
            which = np.concatenate([which, extra_which])
            rows = np.concatenate([rows, stale_rows[extra]])
        return which.astype(np.int64), rows.astype(np.int64)


def _rows_of(graph: RoadGraph, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of segment ``ids`` in ``graph`` and whether each is there at all."""
    all_ids = graph.segs.ids
    if not len(all_ids):
        return np.zeros(len(ids), np.int64), np.zeros(len(ids), bool)
    rows = np.minimum(np.searchsorted(all_ids, ids), len(all_ids) - 1)
    return rows, all_ids[rows] == ids


@dataclass(frozen=True)
class Hits:
    """Segments near query points, per point nearest first (distances to the micrometre; then
    a segment ending at the point, then the lowest id); ``distance_m`` and ``fraction`` are NaN
    for a segment whose coordinates are off the globe (a bad import), which sorts last."""

    point: np.ndarray  # index of the query point
    row: np.ndarray
    distance_m: np.ndarray
    fraction: np.ndarray

    def of(self, i: int) -> Hits:
        """The hits of query point ``i``."""
        lo, hi = np.searchsorted(self.point, [i, i + 1])
        return Hits(self.point[lo:hi], self.row[lo:hi], self.distance_m[lo:hi],
                    self.fraction[lo:hi])

    def __len__(self) -> int:
        return len(self.row)


@kernel("UniTuple(f8[:], 2)(f8[:])")
def metres_per_degree(lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(east, north) metres per degree of longitude and latitude at ``lat``, on WGS84."""
    east, north = np.empty(len(lat)), np.empty(len(lat))
    for i in range(len(lat)):
        w = np.sqrt(1.0 - WGS84_E2 * np.sin(np.radians(lat[i])) ** 2)
        north[i] = WGS84_A * (1.0 - WGS84_E2) / w**3 * DEG
        east[i] = WGS84_A / w * np.cos(np.radians(lat[i])) * DEG
    return east, north


@kernel("f8[:, :](f8[:, :], f8[:], f8[:], f8[:])")
def _boxes(points: np.ndarray, reach: np.ndarray, east: np.ndarray, north: np.ndarray
           ) -> np.ndarray:
    """(min lon, min lat, max lon, max lat) of each point's search area: ``reach`` metres
    around it (at most the whole circle of longitudes)."""
    boxes = np.empty((len(points), 4))
    for i in range(len(points)):
        dlon = min(reach[i] / max(east[i], 1e-3), 360.0)
        dlat = reach[i] / north[i]
        boxes[i] = (points[i, 0] - dlon, points[i, 1] - dlat, points[i, 0] + dlon,
                    points[i, 1] + dlat)
    return boxes


def within(graph: RoadGraph, points: np.ndarray, radius_m: np.ndarray,
           avoid: frozenset[str] = frozenset()) -> Hits:
    """Every segment within ``radius_m[i]`` of ``points[i]`` (lon/lat rows), except those of
    the ``avoid`` classes: where on it the point projects and how far it is, sorted."""
    points = np.ascontiguousarray(points, np.float64).reshape(-1, 2)
    east, north = metres_per_degree(points[:, 1])
    reach = np.asarray(radius_m, np.float64).reshape(-1) * 1.001 + 1e-3
    boxes = _boxes(points, reach, east, north)
    which, rows = graph.index.pairs(graph, boxes)
    if avoid and len(rows):
        keep = ~np.isin(graph.segs.road_class[rows].astype(str), list(avoid))
        which, rows = which[keep], rows[keep]
    distance, fraction = _measure(graph, points, east, north, which, rows)
    near = (distance <= reach[which]) | np.isnan(distance)
    which, rows, distance, fraction = which[near], rows[near], distance[near], fraction[near]
    inner = (fraction > 0.0) & (fraction < 1.0)
    # Distances to the micrometre: the segments meeting at a vertex nearest the point measure
    # the same distance but for floating-point rounding (one reaches the vertex as its start,
    # another as its end), and the order between them is the tie-break's, not the rounding's.
    distance = distance.round(6)
    order = np.lexsort((graph.segs.ids[rows], inner, _nan_last(distance), which))
    return Hits(which[order], rows[order], distance[order], fraction[order])


def _measure(graph: RoadGraph, points: np.ndarray, east: np.ndarray, north: np.ndarray,
             which: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distance m, fraction) from ``points[which]`` to segment ``rows``: the nearest point of
    the line, measured in the query point's local frame (:func:`_nearest_on_lines`)."""
    return _nearest_on_lines(points, east, north, which, rows, graph.segs.offsets,
                             graph.segs.coords, graph.fracs, graph.bbox)


@kernel("f8(f8)")
def _short_way(dlon: float) -> float:
    """A longitude difference taken the short way round the antimeridian."""
    return (dlon + 180.0) % 360.0 - 180.0


@kernel("UniTuple(f8[:], 2)(f8[:, :], f8[:], f8[:], i8[:], i8[:], i8[:], f8[:, :], f8[:], "
        "f8[:, :])")
def _nearest_on_lines(points: np.ndarray, east: np.ndarray, north: np.ndarray,
                      which: np.ndarray, rows: np.ndarray, offsets: np.ndarray,
                      coords: np.ndarray, fracs: np.ndarray, bbox: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """For each (point ``which[i]``, segment ``rows[i]``): the distance in metres to the
    segment's nearest point, each vertex pair measured in the point's local frame (``east``,
    ``north`` metres per degree; longitudes taken the short way round), and that point's
    metric fraction along the segment. The first pair wins a tie; a NaN distance measures as
    infinity; a segment whose bounding box leaves the globe gets NaN for both."""
    n = len(rows)
    distance = np.empty(n)
    fraction = np.empty(n)
    for i in range(n):
        row, p = rows[i], which[i]
        ox, oy, kx, ky = points[p, 0], points[p, 1], east[p], north[p]
        lo, hi = offsets[row], offsets[row + 1]
        best, best_f = np.inf, np.nan
        for k in range(lo, max(hi - 1, lo + 1)):
            nxt = min(k + 1, hi - 1)
            ax = _short_way(coords[k, 0] - ox) * kx
            ay = (coords[k, 1] - oy) * ky
            dx = _short_way(coords[nxt, 0] - coords[k, 0]) * kx
            dy = (coords[nxt, 1] - coords[k, 1]) * ky
            length2 = dx * dx + dy * dy
            t = -(ax * dx + ay * dy) / length2 if length2 > 0.0 else 0.0
            if t < 0.0:
                t = 0.0
            elif t > 1.0:
                t = 1.0
            cx, cy = ax + t * dx, ay + t * dy
            d2 = cx * cx + cy * cy
            if np.isnan(d2):
                d2 = np.inf
            if d2 < best or k == lo:
                best, best_f = d2, fracs[k] + t * (fracs[nxt] - fracs[k])
        distance[i], fraction[i] = np.sqrt(best), best_f
        if bbox[row, 0] < -180.0 or bbox[row, 2] > 180.0 or bbox[row, 1] < -90.0 \
                or bbox[row, 3] > 90.0:
            distance[i], fraction[i] = np.nan, np.nan
    return distance, fraction


def _nan_last(x: np.ndarray) -> np.ndarray:
    """``x`` with NaN as infinity (np.nan_to_num's work, at a fifth of its call overhead)."""
    return np.where(np.isnan(x), np.inf, x)
