"""The in-memory routing graph of one network, built from PostGIS and patched on edits.

Why not pgRouting: ``pgr_dijkstra`` loads the edge table and builds a graph on every call.
Here the segments live in column arrays (numpy) once per worker process, and each cost model
gets a CSR matrix searched by scipy's compiled Dijkstra. An edit re-reads only the segments in
the changed bounding box and rebuilds the arrays (milliseconds), never the whole network.

A :class:`RoadGraph` is immutable once built: updates build a new one and swap it in, so a
query in flight never sees a half-applied edit.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from app.routing.costs import Cost, effective_speed_kph, segment_costs
from app.routing.geometry import bearings, vertex_fractions
from app.routing.hierarchy import Arcs, Hierarchy
from app.routing.settings import routing_settings

ONEWAY_CODES = {"none": 0, "forward": 1, "backward": -1}
MAX_COST_GRAPHS = 6  # per network: cost model × avoid-set combinations kept built

SEGMENT_COLUMNS = (
    "id, source_node, target_node, length_m, speed_limit_kph, oneway, lanes_forward, "
    "lanes_backward, road_class, name, ST_AsBinary(geom)"
)


def _ragged_take(offsets: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets and flat gather indices selecting the variable-length runs ``idx``."""
    lengths = np.diff(offsets)[idx]
    new_offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    gather = np.repeat(offsets[idx] - new_offsets[:-1], lengths) + np.arange(new_offsets[-1])
    return new_offsets, gather


@dataclass(frozen=True)
class Segments:
    """Column arrays of a network's segments, sorted by id; coordinates flat with offsets."""

    ids: np.ndarray
    source: np.ndarray
    target: np.ndarray
    length_m: np.ndarray
    speed_limit: np.ndarray  # km/h, NaN where unknown
    oneway: np.ndarray  # int8: 0 both ways, 1 along the geometry only, -1 against it only
    lanes_forward: np.ndarray
    lanes_backward: np.ndarray
    road_class: np.ndarray  # object (str)
    name: np.ndarray  # object (str | None)
    offsets: np.ndarray  # int64, len = n + 1
    coords: np.ndarray  # float64 (n_vertices, 2), lon/lat

    @classmethod
    def from_rows(cls, rows: Sequence[tuple[Any, ...]]) -> Segments:
        """From rows of :data:`SEGMENT_COLUMNS`."""
        cols = list(zip(*rows, strict=True)) if rows else [()] * 11
        geoms = shapely.from_wkb(np.array(cols[10], dtype=object))
        coords, owner = shapely.get_coordinates(geoms, return_index=True)
        counts = np.bincount(owner, minlength=len(rows))
        segs = cls(
            ids=np.array(cols[0], dtype=np.int64),
            source=np.array(cols[1], dtype=np.int64),
            target=np.array(cols[2], dtype=np.int64),
            length_m=np.array(cols[3], dtype=np.float64),
            speed_limit=np.array([np.nan if v is None else v for v in cols[4]], dtype=np.float64),
            oneway=np.array([ONEWAY_CODES[v] for v in cols[5]], dtype=np.int8),
            lanes_forward=np.array(cols[6], dtype=np.int16),
            lanes_backward=np.array(cols[7], dtype=np.int16),
            road_class=np.array(cols[8], dtype=object),
            name=np.array(cols[9], dtype=object),
            offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            coords=coords.reshape(-1, 2).astype(np.float64),
        )
        return segs.take(np.argsort(segs.ids, kind="stable"))

    def __len__(self) -> int:
        return len(self.ids)

    def take(self, idx: np.ndarray) -> Segments:
        """The rows ``idx`` (with their coordinates), for patching part of a graph."""
        offsets, gather = _ragged_take(self.offsets, idx)
        per_row = {name: getattr(self, name)[idx] for name in _ROW_FIELDS}
        return Segments(**per_row, offsets=offsets, coords=self.coords[gather])

    def concat(self, other: Segments) -> Segments:
        """Both sets of rows, re-sorted by id."""
        per_row = {name: np.concatenate([getattr(self, name), getattr(other, name)])
                   for name in _ROW_FIELDS}
        offsets = np.concatenate([self.offsets[:-1], other.offsets + self.offsets[-1]])
        joined = Segments(**per_row, offsets=offsets,
                          coords=np.concatenate([self.coords, other.coords]))
        return joined.take(np.argsort(joined.ids, kind="stable"))

    def bboxes(self) -> np.ndarray:
        """(n, 4) minlon, minlat, maxlon, maxlat per segment."""
        if not len(self):
            return np.zeros((0, 4))
        starts = self.offsets[:-1]
        lo = np.minimum.reduceat(self.coords, starts, axis=0)
        hi = np.maximum.reduceat(self.coords, starts, axis=0)
        return np.hstack([lo, hi])


_ROW_FIELDS = ("ids", "source", "target", "length_m", "speed_limit", "oneway", "lanes_forward",
               "lanes_backward", "road_class", "name")


@dataclass
class CostGraph:
    """A CSR matrix of allowed arcs under one cost model, plus a virtual origin row.

    Row ``origin`` (the last) is the query's start point: its two slots are rewritten per search
    to point at the snapped segment's end nodes with the partial costs, so a route can start
    mid-segment without copying the matrix. Parallel arcs are reduced to the cheapest, which is
    also what Dijkstra would pick, so each (tail, head) pair maps to one segment.
    """

    seg_cost: np.ndarray
    matrix: csr_matrix
    arc_row: np.ndarray  # segment row of each CSR entry
    arc_dir: np.ndarray  # +1 along the geometry, -1 against it
    arc_key: np.ndarray  # tail * (origin + 1) + head, ascending, for vectorised arc lookup
    origin: int
    max_rate: float  # most metres per unit of cost on any segment (top speed in m/s for time)
    total_cost: float  # of all segments: a bound beyond which a search is unbounded anyway
    lock: threading.Lock = field(default_factory=threading.Lock)
    hierarchy: Hierarchy | None = None  # the shape's CCH, when the network is large enough
    hierarchy_key: object = None
    version: int = 0
    arc_costs: np.ndarray | None = None  # per hierarchy arc, inf where not allowed

    SLOTS = 2

    def fast_path(self, outs: Sequence[tuple[int, float]], ins: Sequence[tuple[int, float]]
                  ) -> tuple[int, int, np.ndarray, np.ndarray] | None:
        """Through the hierarchy: (departure index, arrival index, segment rows, directions)
        of the cheapest way, or ``None`` when the hierarchy cannot answer for this version
        (not built yet, superseded, or no path within its range): then search with Dijkstra."""
        if self.hierarchy is None or self.arc_costs is None:
            return None
        metric = self.hierarchy.metric(self.hierarchy_key, self.version, self.arc_costs,
                                       self.max_rate)
        found = metric.shortest(self.version, outs, ins) if metric is not None else None
        if found is None:
            return None
        i, j, arcs = found
        self.hierarchy.answered += 1
        return i, j, self.hierarchy.arcs.row[arcs], self.hierarchy.arcs.way[arcs]

    def search(self, departures: Iterable[tuple[int, float]],
               limit: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Dijkstra from the virtual origin: distances and predecessors of every node."""
        arcs = list(departures)[: self.SLOTS]
        arcs += [arcs[0]] * (self.SLOTS - len(arcs))
        with self.lock:
            self.matrix.indices[-self.SLOTS:] = [node for node, _ in arcs]
            self.matrix.data[-self.SLOTS:] = [c for _, c in arcs]
            dist, pred = dijkstra(self.matrix, directed=True, indices=self.origin,
                                  return_predecessors=True, limit=limit)
        return dist, pred

    def path_arcs(self, nodes: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """(segment rows, directions) of the arcs joining consecutive graph nodes."""
        path = np.asarray(nodes, dtype=np.int64)
        k = np.searchsorted(self.arc_key, path[:-1] * (self.origin + 1) + path[1:])
        return self.arc_row[k], self.arc_dir[k]


@dataclass(frozen=True)
class Shape:
    """What a graph derives from segment ends and geometry, so an attribute-only edit (speed
    limit, one-way, lanes: most edits) can reuse it instead of recomputing it."""

    node_ids: np.ndarray
    u: np.ndarray  # node index of each segment's source
    v: np.ndarray  # ... and target
    fracs: np.ndarray  # metric fraction of each vertex along its segment
    bbox: np.ndarray  # (n, 4) per segment
    bearing_start: np.ndarray  # compass bearing leaving the first vertex, forward
    bearing_end: np.ndarray  # ... and reaching the last
    hierarchy: Hierarchy | None  # built lazily in the background, shared while arcs stay

    @classmethod
    def of(cls, s: Segments, previous: Shape | None = None) -> Shape:
        """Node ids, end bearings and vertex fractions of the segments, computed once per graph so
        responses need no per-request geometry work.

        ``previous``: the shape this one replaces; its hierarchy is kept when the arcs are
        the same (a geometry edit that keeps both end nodes changes lengths, not arcs)."""
        node_ids, inverse = np.unique(np.concatenate([s.source, s.target]), return_inverse=True)
        u, v = inverse[: len(s)].astype(np.int32), inverse[len(s):].astype(np.int32)
        same_arcs = previous is not None and np.array_equal(previous.node_ids, node_ids) and \
            np.array_equal(previous.u, u) and np.array_equal(previous.v, v)
        hierarchy = previous.hierarchy if same_arcs and previous is not None else None
        if hierarchy is None and len(s) >= max(1, routing_settings().hierarchy_min_segments):
            lonlat = np.zeros((len(node_ids), 2))
            lonlat[u], lonlat[v] = s.coords[s.offsets[:-1]], s.coords[s.offsets[1:] - 1]
            hierarchy = Hierarchy(Arcs.of(u, v), lonlat)
        fracs = vertex_fractions(s.coords, s.offsets) if len(s) else np.zeros(0)
        return cls(node_ids, u, v, fracs, s.bboxes(), *_end_bearings(s), hierarchy)


def _end_bearings(s: Segments) -> tuple[np.ndarray, np.ndarray]:
    """Compass bearing leaving each segment's first vertex and reaching its last."""
    if not len(s):
        return np.zeros(0), np.zeros(0)
    first, last = s.offsets[:-1], s.offsets[1:] - 1
    return bearings(s.coords[first], s.coords[first + 1]), bearings(s.coords[last - 1],
                                                                     s.coords[last])


@dataclass
class RoadGraph:
    """One network's segments with node indexing; cost graphs are built lazily and cached."""

    network_id: int
    version: int
    segs: Segments
    shape: Shape | None = None
    _costs: dict[tuple[Cost, frozenset[str]], CostGraph] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        shape = self.shape = self.shape or Shape.of(self.segs)
        self.node_ids, self.u, self.v, self.fracs = shape.node_ids, shape.u, shape.v, shape.fracs
        self.bbox, self.bearing_start, self.bearing_end = (shape.bbox, shape.bearing_start,
                                                           shape.bearing_end)
        self.speed_kph = effective_speed_kph(self.segs.speed_limit, self.segs.road_class)

    @property
    def n_nodes(self) -> int:
        """Number of distinct nodes (the CSR matrices' size)."""
        return len(self.node_ids)

    def row_of(self, segment_id: int) -> int | None:
        """The row holding ``segment_id`` (rows are sorted by id), or None if it is not in this
        graph."""
        k = int(np.searchsorted(self.segs.ids, segment_id))
        return k if k < len(self.segs) and self.segs.ids[k] == segment_id else None

    def line(self, row: int) -> tuple[np.ndarray, np.ndarray]:
        """Coordinates and vertex fractions of one segment."""
        lo, hi = self.segs.offsets[row], self.segs.offsets[row + 1]
        return self.segs.coords[lo:hi], self.fracs[lo:hi]

    def costs(self, cost: Cost, avoid: frozenset[str] = frozenset()) -> CostGraph:
        """The cost graph for a cost model and avoided road classes (a few kept, LRU)."""
        key = (cost, avoid)
        with self._lock:
            cg = self._costs.pop(key, None) or self._build_costs(cost, avoid)
            self._costs[key] = cg  # most recently used last
            while len(self._costs) > MAX_COST_GRAPHS:
                del self._costs[next(iter(self._costs))]
            return cg

    def _build_costs(self, cost: Cost, avoid: frozenset[str]) -> CostGraph:
        s = self.segs
        seg_cost = segment_costs(cost, s.length_m, self.speed_kph)
        usable = ~np.isin(s.road_class, list(avoid)) if avoid else np.ones(len(s), bool)
        usable &= self.u != self.v  # a loop never shortens a path
        rows = np.arange(len(s))
        fwd = usable & (s.oneway >= 0)
        bwd = usable & (s.oneway <= 0)
        tail = np.concatenate([self.u[fwd], self.v[bwd]])
        head = np.concatenate([self.v[fwd], self.u[bwd]])
        arc_row = np.concatenate([rows[fwd], rows[bwd]])
        arc_dir = np.concatenate([np.ones(fwd.sum(), np.int8), -np.ones(bwd.sum(), np.int8)])
        weight = seg_cost[arc_row]
        priced = weight > 0
        max_rate = float((s.length_m[arc_row][priced] / weight[priced]).max(initial=1.0))
        order = np.lexsort((weight, head, tail))
        tail, head, arc_row, arc_dir, weight = (a[order] for a in
                                                (tail, head, arc_row, arc_dir, weight))
        first = np.ones(len(tail), bool)
        first[1:] = (tail[1:] != tail[:-1]) | (head[1:] != head[:-1])
        tail, head, arc_row, arc_dir, weight = (a[first] for a in
                                                (tail, head, arc_row, arc_dir, weight))
        n = self.n_nodes
        indptr = np.searchsorted(tail, np.arange(n + 1)).astype(np.int32)
        indptr = np.append(indptr, indptr[-1] + CostGraph.SLOTS).astype(np.int32)
        pad = CostGraph.SLOTS
        matrix = csr_matrix(
            (np.append(weight, np.zeros(pad)),
             np.append(head, np.zeros(pad)).astype(np.int32),
             indptr),
            shape=(n + 1, n + 1),
        )
        cg = CostGraph(seg_cost=seg_cost, matrix=matrix,
                       arc_row=np.append(arc_row, -np.ones(pad, np.int64)),
                       arc_dir=np.append(arc_dir, np.zeros(pad, np.int8)),
                       arc_key=tail.astype(np.int64) * (n + 1) + head, origin=n,
                       max_rate=max_rate, total_cost=float(weight.sum()))
        hierarchy = self.shape.hierarchy if self.shape is not None else None
        if hierarchy is not None:
            arcs = hierarchy.arcs
            allowed = usable[arcs.row] & np.where(arcs.way > 0, s.oneway[arcs.row] >= 0,
                                                  s.oneway[arcs.row] <= 0)
            cg.hierarchy, cg.hierarchy_key, cg.version = hierarchy, (cost, avoid), self.version
            cg.arc_costs = np.where(allowed, seg_cost[arcs.row], np.inf)
            hierarchy.metric(cg.hierarchy_key, self.version, cg.arc_costs, max_rate)
        return cg

    def patched(self, version: int, box: Sequence[float], fresh: Segments) -> RoadGraph:
        """A new graph where every segment inside ``box`` is replaced by ``fresh``.

        ``fresh`` holds the current rows of the segments whose geometry meets ``box``; any
        graph segment meeting it that is not in ``fresh`` was deleted (its old geometry is
        part of the box the database announced).
        """
        minx, miny, maxx, maxy = box
        b = self.bbox
        inside = (b[:, 0] <= maxx) & (b[:, 2] >= minx) & (b[:, 1] <= maxy) & (b[:, 3] >= miny)
        stale = inside | np.isin(self.segs.ids, fresh.ids)
        rows = np.flatnonzero(stale)
        if self._same_shape(rows, fresh):
            return RoadGraph(self.network_id, version, self._with_attributes(rows, fresh),
                             shape=self.shape)
        segs = self.segs.take(np.flatnonzero(~stale)).concat(fresh)
        return RoadGraph(self.network_id, version, segs, shape=Shape.of(segs, self.shape))

    def _same_shape(self, rows: np.ndarray, fresh: Segments) -> bool:
        """True when ``fresh`` are exactly the segments at ``rows``, with the same ends and
        geometry: only attributes changed."""
        old = self.segs
        if not np.array_equal(old.ids[rows], fresh.ids):
            return False
        if not (np.array_equal(old.source[rows], fresh.source)
                and np.array_equal(old.target[rows], fresh.target)):
            return False
        offsets, gather = _ragged_take(old.offsets, rows)
        return (np.array_equal(offsets, fresh.offsets)
                and np.array_equal(old.coords[gather], fresh.coords))

    def _with_attributes(self, rows: np.ndarray, fresh: Segments) -> Segments:
        columns = {}
        for name in _ROW_FIELDS:
            column = getattr(self.segs, name).copy()
            column[rows] = getattr(fresh, name)
            columns[name] = column
        return Segments(**columns, offsets=self.segs.offsets, coords=self.segs.coords)
