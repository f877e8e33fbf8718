"""Segments near points, found in memory: what every routing service snaps with.

Why in memory: snapping by PostGIS (a KNN walk per point, then each candidate projected in
its UTM zone and measured on the spheroid) was 2-3 ms of a city route's ~9 ms, and a
1,000-point trace to match would pay it a thousand times. The graph already holds every
segment's coordinates, so a grid over the segments' bounding boxes (:class:`Grid`) finds the
candidates, and each is measured in the point's local metric frame (WGS84 radii of curvature
at the point: within 1e-4 of the spheroid's distance over a few kilometres, like the UTM
projection it replaces). Fractions are read off the graph's metric vertex fractions, the ones
the engine prices pieces with. Finding, measuring and ordering the candidates of every point
is one compiled call (:func:`_near`): through shapely's STRtree and numpy it was ~20 array
and geometry calls per request (36 us in a loop for a route's two points, ~90 us of a live
route; 16 us compiled, most of it passing the call its arrays).

Kept current under live edits without rebuilding the grid: a graph version's index is the
grid of the version it was built on plus the ids of the segments added or changed since
(``stale``, few): grid hits of a stale id are dropped and the stale segments are tested
directly, and a deleted segment's hits find no row. Once more than :data:`STALE_MAX` (or
0.2 % of the network) have changed, the next version builds a new grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from app.routing.native import kernel

if TYPE_CHECKING:
    from app.routing.graph import RoadGraph

STALE_MAX = 1024
LARGE_CELLS = 256  # a box over more cells than this is kept aside and tested by every query
WGS84_A = 6_378_137.0
WGS84_E2 = 0.00669437999014
DEG = math.pi / 180.0


@dataclass(frozen=True)
class Grid:
    """Bounding boxes bucketed in a uniform grid of about one box per cell, for compiled
    queries: each box is listed in every cell it covers (a box over more than
    :data:`LARGE_CELLS` cells in ``large``, tested by every query), and a query reports a box
    once, from the cell holding the lower-left corner of the two boxes' overlap. Why not
    shapely's STRtree, which it replaced: a query from compiled code cannot reach it, and from
    Python it cost a city route ~20 us of geometry construction and call overhead for two
    points. Boxes with a NaN or infinite bound are in no cell and meet nothing. The grid keeps
    no copy of the boxes: a query reads each item's box off the graph (:func:`_rows_meeting`)."""

    frame: np.ndarray  # x0, y0, cell width, cell height
    dims: np.ndarray  # cells across (x), cells up (y)
    start: np.ndarray  # (nx * ny + 1,) where each cell's items start in ``items``
    items: np.ndarray  # box indices, cell by cell
    large: np.ndarray  # indices of the boxes over more than LARGE_CELLS cells

    @classmethod
    def of(cls, boxes: np.ndarray) -> Grid:
        """The grid of ``boxes`` ((n, 4) min x, min y, max x, max y)."""
        boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
        finite = np.isfinite(boxes).all(axis=1)
        n = max(int(finite.sum()), 1)
        lo = boxes[finite, :2].min(axis=0) if finite.any() else np.zeros(2)
        hi = boxes[finite, 2:].max(axis=0) if finite.any() else np.zeros(2)
        width, height = hi - lo
        if width > 0 and height > 0:
            nx = math.ceil(math.sqrt(n * width / height))
            ny = math.ceil(math.sqrt(n * height / width))
        else:
            nx, ny = (n, 1) if width > 0 else (1, n if height > 0 else 1)
        nx, ny = min(nx, n), min(ny, n)
        frame = np.array([lo[0], lo[1], width / nx if width > 0 else 1.0,
                          height / ny if height > 0 else 1.0])
        dims = np.array([nx, ny], np.int64)
        start, items, large = _bucket(boxes, frame, dims)
        return cls(frame, dims, start, items, large)


@kernel("i8(f8, f8, f8, i8)")
def _cell(x: float, origin: float, size: float, n: int) -> int:
    """The cell of coordinate ``x`` along one axis, clamped to the grid (finite ``x``)."""
    k = (x - origin) / size
    if k < 0.0:
        return 0
    if k >= n:
        return n - 1
    return int(k)


@kernel("UniTuple(i8, 4)(f8[:], f8[:], i8[:])")
def _span(box: np.ndarray, frame: np.ndarray, dims: np.ndarray) -> tuple[int, int, int, int]:
    """The first and last cells across, then up, that a finite ``box`` covers."""
    return (_cell(box[0], frame[0], frame[2], dims[0]), _cell(box[2], frame[0], frame[2], dims[0]),
            _cell(box[1], frame[1], frame[3], dims[1]), _cell(box[3], frame[1], frame[3], dims[1]))


@kernel("b1(f8[:])")
def _finite(box: np.ndarray) -> bool:
    """Whether every bound of ``box`` is a finite number."""
    return (np.isfinite(box[0]) and np.isfinite(box[1]) and np.isfinite(box[2])
            and np.isfinite(box[3]))


@kernel("UniTuple(i8[:], 3)(f8[:, :], f8[:], i8[:])")
def _bucket(boxes: np.ndarray, frame: np.ndarray, dims: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(start, items, large) of :class:`Grid` for ``boxes``."""
    nx, ny = dims[0], dims[1]
    n = len(boxes)
    kind = np.zeros(n, np.int8)  # 0 in no cell, 1 in its cells, 2 large
    count = np.zeros(nx * ny + 1, np.int64)
    for i in range(n):
        if not _finite(boxes[i]):
            continue
        x0, x1, y0, y1 = _span(boxes[i], frame, dims)
        if (x1 - x0 + 1) * (y1 - y0 + 1) > LARGE_CELLS:
            kind[i] = 2
            continue
        kind[i] = 1
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                count[y * nx + x + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    items = np.empty(start[-1], np.int64)
    for i in range(n):
        if kind[i] != 1:
            continue
        x0, x1, y0, y1 = _span(boxes[i], frame, dims)
        for y in range(y0, y1 + 1):
            for x in range(x0, x1 + 1):
                items[fill[y * nx + x]] = i
                fill[y * nx + x] += 1
    return start, items, np.flatnonzero(kind == 2).astype(np.int64)


@kernel("b1(f8[:], f8, f8, f8, f8)")
def _meets(box: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> bool:
    """Whether ``box`` meets (x0, y0, x1, y1), edges included."""
    return box[0] <= x1 and box[2] >= x0 and box[1] <= y1 and box[3] >= y0


@kernel("i8(i8[:], i8)")
def _find(sorted_ids: np.ndarray, value: int) -> int:
    """Where ``value`` is in ascending ``sorted_ids``, or -1."""
    k = int(np.searchsorted(sorted_ids, value))
    return k if k < len(sorted_ids) and sorted_ids[k] == value else -1


@kernel("i8(i8, i8[:], i8[:], i8[:])")
def _current_row(item: int, ids: np.ndarray, stale: np.ndarray, current: np.ndarray) -> int:
    """The current graph's row of grid item ``item``, or -1 when its segment was edited since
    the grid was built (``stale``: tested apart) or is gone. A row found holds the box the
    item was bucketed by. Items are the rows of the graph the grid was built on, which most
    later versions keep (only a split or a merge moves rows): looked up only when moved."""
    if len(stale) and _find(stale, ids[item]) >= 0:
        return -1
    if item < len(current) and current[item] == ids[item]:
        return item
    return _find(current, ids[item])


@kernel("i8[:](f8[:], f8[:], i8[:], i8[:], i8[:], i8[:], i8[:], i8[:], i8[:], f8[:, :])")
def _rows_meeting(q: np.ndarray, frame: np.ndarray, dims: np.ndarray, start: np.ndarray,
                  items: np.ndarray, large: np.ndarray, ids: np.ndarray, stale: np.ndarray,
                  current: np.ndarray, bbox: np.ndarray) -> np.ndarray:
    """Rows of the current graph (segment ids ``current``, boxes ``bbox``) whose box meets
    ``q``: the grid's items (``ids`` their segment ids) not ``stale``, and the stale
    segments still present."""
    found = np.empty(16, np.int64)
    k = 0
    if not _finite(q):
        return found[:0]
    nx, ny = dims[0], dims[1]
    x0, x1, y0, y1 = _span(q, frame, dims)
    for y in range(y0, y1 + 1):
        for x in range(x0, x1 + 1):
            cell = y * nx + x
            for j in range(start[cell], start[cell + 1]):
                row = _current_row(items[j], ids, stale, current)
                if row < 0:
                    continue
                b = bbox[row]
                if not _meets(b, q[0], q[1], q[2], q[3]):
                    continue
                # Reported from one cell only: the one holding the overlap's lower-left corner.
                if (_cell(max(b[0], q[0]), frame[0], frame[2], nx) != x
                        or _cell(max(b[1], q[1]), frame[1], frame[3], ny) != y):
                    continue
                if k == len(found):
                    found = np.concatenate((found, np.empty(k, np.int64)))
                found[k] = row
                k += 1
    extra = np.empty(len(large) + len(stale), np.int64)
    m = 0
    for item in large:
        row = _current_row(item, ids, stale, current)
        if row >= 0 and _meets(bbox[row], q[0], q[1], q[2], q[3]):
            extra[m] = row
            m += 1
    for sid in stale:
        row = _find(current, sid)
        if row >= 0 and _meets(bbox[row], q[0], q[1], q[2], q[3]):
            extra[m] = row
            m += 1
    return np.concatenate((found[:k], extra[:m]))


# What the compiled queries read of an index and the current graph (SegmentIndex.arrays).
IndexArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                    np.ndarray, np.ndarray, np.ndarray]


@dataclass(frozen=True)
class SegmentIndex:
    """The :class:`Grid` of the segments of the version it was built on, and what changed
    since."""

    grid: Grid
    ids: np.ndarray  # segment id of each grid item
    stale: np.ndarray  # ascending ids added or changed since the grid was built

    @classmethod
    def of(cls, graph: RoadGraph) -> SegmentIndex:
        """The index of every segment of ``graph``."""
        return cls(Grid.of(graph.bbox), graph.segs.ids.copy(), np.zeros(0, np.int64))

    def after(self, changed: np.ndarray, n_rows: int) -> SegmentIndex | None:
        """This index for the next version, where the segments ``changed`` were added or
        edited; ``None`` when so many changed that a new grid pays off."""
        stale = np.union1d(self.stale, changed)
        if len(stale) > max(STALE_MAX, n_rows // 500):
            return None
        return SegmentIndex(self.grid, self.ids, stale)

    def arrays(self, graph: RoadGraph) -> IndexArrays:
        """What :func:`_rows_meeting` reads after the query box, for ``graph``."""
        g = self.grid
        return (g.frame, g.dims, g.start, g.items, g.large, self.ids, self.stale,
                graph.segs.ids, graph.bbox)

    def pairs(self, graph: RoadGraph, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(box index, segment row) of every current segment whose bounding box meets one of
        ``boxes`` ((m, 4) min lon, min lat, max lon, max lat)."""
        return _pairs(np.ascontiguousarray(boxes, np.float64).reshape(-1, 4),
                      *self.arrays(graph))


@kernel("UniTuple(i8[:], 2)(f8[:, :], f8[:], i8[:], i8[:], i8[:], i8[:], i8[:], i8[:], "
        "i8[:], f8[:, :])")
def _pairs(queries: np.ndarray, frame: np.ndarray, dims: np.ndarray, start: np.ndarray,
           items: np.ndarray, large: np.ndarray, ids: np.ndarray, stale: np.ndarray,
           current: np.ndarray, bbox: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """(query index, row) of :meth:`SegmentIndex.pairs`, query by query."""
    which = np.empty(4 * len(queries) + 16, np.int64)
    rows = np.empty(len(which), np.int64)
    n = 0
    for i in range(len(queries)):
        found = _rows_meeting(queries[i], frame, dims, start, items, large, ids, stale,
                              current, bbox)
        if n + len(found) > len(which):
            more = max(len(which), len(found))
            which = np.concatenate((which, np.empty(more, np.int64)))
            rows = np.concatenate((rows, np.empty(more, np.int64)))
        which[n:n + len(found)] = i
        rows[n:n + len(found)] = found
        n += len(found)
    return which[:n], rows[:n]


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


@kernel("UniTuple(f8, 2)(f8)")
def _scale(lat: float) -> tuple[float, float]:
    """(east, north) metres per degree of longitude and latitude at ``lat``, on WGS84."""
    w = np.sqrt(1.0 - WGS84_E2 * np.sin(np.radians(lat)) ** 2)
    return WGS84_A / w * np.cos(np.radians(lat)) * DEG, WGS84_A * (1.0 - WGS84_E2) / w**3 * DEG


@kernel("f8(f8)")
def _short_way(dlon: float) -> float:
    """A longitude difference taken the short way round the antimeridian."""
    return (dlon + 180.0) % 360.0 - 180.0


@kernel("UniTuple(f8, 2)(f8, f8, f8, f8, i8, i8[:], f8[:, :], f8[:], f8[:, :])")
def _nearest_on_line(ox: float, oy: float, east: float, north: float, row: int,
                     offsets: np.ndarray, coords: np.ndarray, fracs: np.ndarray,
                     bbox: np.ndarray) -> tuple[float, float]:
    """The distance in metres from (``ox``, ``oy``) to segment ``row``'s nearest point, each
    vertex pair measured in the point's local frame (``east``, ``north`` metres per degree;
    longitudes taken the short way round), and that point's metric fraction along the
    segment. The first pair wins a tie; a NaN distance measures as infinity; a segment whose
    bounding box leaves the globe gets NaN for both."""
    if bbox[row, 0] < -180.0 or bbox[row, 2] > 180.0 or bbox[row, 1] < -90.0 \
            or bbox[row, 3] > 90.0:
        return np.nan, np.nan
    lo, hi = offsets[row], offsets[row + 1]
    best, best_f = np.inf, np.nan
    for k in range(lo, max(hi - 1, lo + 1)):
        nxt = min(k + 1, hi - 1)
        ax = _short_way(coords[k, 0] - ox) * east
        ay = (coords[k, 1] - oy) * north
        dx = _short_way(coords[nxt, 0] - coords[k, 0]) * east
        dy = (coords[nxt, 1] - coords[k, 1]) * north
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
    return np.sqrt(best), best_f


def within(graph: RoadGraph, points: np.ndarray, radius_m: np.ndarray,
           avoid: frozenset[str] = frozenset()) -> Hits:
    """Every segment within ``radius_m[i]`` of ``points[i]`` (lon/lat rows), except those of
    the ``avoid`` classes: where on it the point projects and how far it is, sorted."""
    points = np.ascontiguousarray(points, np.float64).reshape(-1, 2)
    reach = np.asarray(radius_m, np.float64).reshape(-1) * 1.001 + 1e-3
    s = graph.segs
    which, rows, distance, fraction = _near(points, reach, *graph.index.arrays(graph),
                                            s.offsets, s.coords, graph.fracs)
    if avoid and len(rows):
        keep = ~np.isin(s.road_class[rows].astype(str), list(avoid))
        which, rows, distance, fraction = which[keep], rows[keep], distance[keep], fraction[keep]
    return Hits(which, rows, distance, fraction)


@kernel("Tuple((i8[:], i8[:], f8[:], f8[:]))(f8[:, :], f8[:], f8[:], i8[:], i8[:], i8[:], "
        "i8[:], i8[:], i8[:], i8[:], f8[:, :], i8[:], f8[:, :], f8[:])")
def _near(points: np.ndarray, reach: np.ndarray, frame: np.ndarray, dims: np.ndarray,
          start: np.ndarray, items: np.ndarray, large: np.ndarray,
          ids: np.ndarray, stale: np.ndarray, current: np.ndarray, bbox: np.ndarray,
          offsets: np.ndarray, coords: np.ndarray, fracs: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(point index, row, distance m, fraction) of every segment within ``reach[i]`` of
    ``points[i]``, sorted as :class:`Hits` says: each point's search box (``reach`` metres
    around it, at most the whole circle of longitudes), the rows whose box meets it
    (:func:`_rows_meeting`), each measured (:func:`_nearest_on_line`)."""
    cap = 8 * len(points) + 16
    out_which, out_rows = np.empty(cap, np.int64), np.empty(cap, np.int64)
    out_distance, out_fraction = np.empty(cap), np.empty(cap)
    n = 0
    for p in range(len(points)):
        ox, oy = points[p, 0], points[p, 1]
        east, north = _scale(oy)
        dlon = min(reach[p] / max(east, 1e-3), 360.0)
        dlat = reach[p] / north
        q = np.array([ox - dlon, oy - dlat, ox + dlon, oy + dlat])
        rows = _rows_meeting(q, frame, dims, start, items, large, ids, stale, current, bbox)
        distance = np.empty(len(rows))
        fraction = np.empty(len(rows))
        for i in range(len(rows)):
            distance[i], fraction[i] = _nearest_on_line(ox, oy, east, north, rows[i], offsets,
                                                        coords, fracs, bbox)
        keep = (distance <= reach[p]) | np.isnan(distance)
        rows, distance, fraction = rows[keep], distance[keep], fraction[keep]
        # Distances to the micrometre (numpy's rounding): the segments meeting at a vertex
        # nearest the point measure the same distance but for floating-point rounding (one
        # reaches the vertex as its start, another as its end), and the order between them is
        # the tie-break's, not the rounding's.
        distance = np.rint(distance * 1e6) / 1e6
        key = np.where(np.isnan(distance), np.inf, distance)
        inner = (fraction > 0.0) & (fraction < 1.0)
        # Nearest first, then a segment ending at the point, then the lowest id: stable sorts
        # from the last key to the first (a point far from every road, asked with a 10 km
        # radius, may have thousands of candidates).
        order = np.argsort(current[rows], kind="mergesort")
        order = order[np.argsort(inner[order].astype(np.int8), kind="mergesort")]
        order = order[np.argsort(key[order], kind="mergesort")]
        if n + len(rows) > cap:
            more = max(cap, len(rows))
            cap += more
            out_which = np.concatenate((out_which, np.empty(more, np.int64)))
            out_rows = np.concatenate((out_rows, np.empty(more, np.int64)))
            out_distance = np.concatenate((out_distance, np.empty(more)))
            out_fraction = np.concatenate((out_fraction, np.empty(more)))
        out_which[n:n + len(rows)] = p
        out_rows[n:n + len(rows)] = rows[order]
        out_distance[n:n + len(rows)] = distance[order]
        out_fraction[n:n + len(rows)] = fraction[order]
        n += len(rows)
    return out_which[:n], out_rows[:n], out_distance[:n], out_fraction[:n]
