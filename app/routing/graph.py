"""The in-memory routing graph of one network, built from PostGIS and patched on edits.

Why not pgRouting: ``pgr_dijkstra`` loads the edge table and builds a graph on every call.
Here the segments live in column arrays (numpy) once per worker process, and each cost model
gets one weight per arc of a shared arc table (:mod:`app.routing.arcs`), searched by scipy's
compiled Dijkstra or by the network's contraction hierarchy.

A :class:`RoadGraph` is immutable once built: updates build a new one and swap it in, so a
query in flight never sees a half-applied edit. An edit that keeps every segment's end nodes
(attributes, or a geometry with the same ends: most edits) costs work in proportion to the
rows it touches, not to the network: the new version shares every array the edit leaves
alone and copies the others with the changed rows patched (:func:`_replaced`), and each
cost model patches the weights of the touched rows' arcs. On a million segments that is
tens of milliseconds where rebuilding took seconds.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import shapely
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from app.routing.arcs import Arcs
from app.routing.costs import Cost, effective_speed_kph, segment_costs
from app.routing.geometry import bearings, vertex_fractions
from app.routing.hierarchy import Hierarchy, Metric
from app.routing.nearby import SegmentIndex
from app.routing.profiles import DEFAULT
from app.routing.settings import routing_settings
from app.routing.splice import Layout, ragged_take, replaced, spliced

ONEWAY_CODES = {"none": 0, "forward": 1, "backward": -1}
MAX_COST_GRAPHS = 6  # per network: cost model × avoid-set combinations kept built
SPLICE_MAX_ROWS = 10_000  # rows an edit adds or removes beyond which a graph is rebuilt
# Right after an edit a route may wait this long (per arc of the network, at most the max) for
# the hierarchy's update to its version rather than run Dijkstra: about half of what a
# Dijkstra across the network costs (60 ms of ~120 ms at 1M segments), so waiting pays off
# for a side-street edit (milliseconds) and costs little when a motorway edit takes longer.
METRIC_WAIT_S_PER_ARC = 3e-8
METRIC_WAIT_MAX_S = 0.1

# The last two are OSM tags kept in ``attrs`` that steps need (a road's ``ref``, and whether it
# is part of a roundabout): loaded with the rest, so shaping steps never reads the database.
SEGMENT_COLUMNS = (
    "id, source_node, target_node, length_m, speed_limit_kph, oneway, lanes_forward, "
    "lanes_backward, road_class, name, ST_AsBinary(geom), attrs->>'ref', "
    "COALESCE(attrs->>'junction' IN ('roundabout', 'circular'), false)"
)


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
    ref: np.ndarray  # object (str | None): OSM ref, for steps
    roundabout: np.ndarray  # bool: OSM junction=roundabout|circular, for steps
    offsets: np.ndarray  # int64, len = n + 1
    coords: np.ndarray  # float64 (n_vertices, 2), lon/lat

    @classmethod
    def from_rows(cls, rows: Sequence[tuple[Any, ...]]) -> Segments:
        """From rows of :data:`SEGMENT_COLUMNS`."""
        cols = list(zip(*rows, strict=True)) if rows else [()] * 13
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
            ref=np.array(cols[11], dtype=object),
            roundabout=np.array(cols[12], dtype=bool),
            offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            coords=coords.reshape(-1, 2).astype(np.float64),
        )
        return segs.take(np.argsort(segs.ids, kind="stable"))

    def __len__(self) -> int:
        return len(self.ids)

    def take(self, idx: np.ndarray) -> Segments:
        """The rows ``idx`` (with their coordinates), for patching part of a graph."""
        offsets, gather = ragged_take(self.offsets, idx)
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

    def replaced(self, rows: np.ndarray, fresh: Segments) -> Segments:
        """These segments with ``rows`` (ascending) replaced by ``fresh`` (same ids), sharing
        every column the replacement leaves unchanged."""
        per_row = {name: replaced(getattr(self, name), rows, getattr(fresh, name))
                   for name in _ROW_FIELDS}
        offsets, coords = spliced(self.offsets, self.coords, rows, fresh.offsets, fresh.coords)
        return Segments(**per_row, offsets=offsets, coords=coords)

    def spliced(self, layout: Layout, fresh: Segments) -> Segments:
        """The rows of ``layout``: these segments' kept rows around ``fresh``."""
        per_row = {name: layout.join(getattr(self, name), getattr(fresh, name))
                   for name in _ROW_FIELDS}
        offsets, coords = layout.join_ragged(self.offsets, self.coords, fresh.offsets,
                                             fresh.coords)
        return Segments(**per_row, offsets=offsets, coords=coords)

    def bboxes(self) -> np.ndarray:
        """(n, 4) minlon, minlat, maxlon, maxlat per segment."""
        if not len(self):
            return np.zeros((0, 4))
        starts = self.offsets[:-1]
        lo = np.minimum.reduceat(self.coords, starts, axis=0)
        hi = np.maximum.reduceat(self.coords, starts, axis=0)
        return np.hstack([lo, hi])


_ROW_FIELDS = ("ids", "source", "target", "length_m", "speed_limit", "oneway", "lanes_forward",
               "lanes_backward", "road_class", "name", "ref", "roundabout")


@dataclass
class CostGraph:
    """One cost model's weights over the shape's arcs, searched by Dijkstra or the hierarchy.

    ``weights`` holds one cost per arc of :class:`Arcs` (infinite where the direction is not
    allowed) followed by :data:`SLOTS` entries for a virtual origin: together with the arc
    table's ``head``/``indptr`` they form the CSR matrix of the Dijkstra search, built on the
    first search only (once the hierarchy answers, most versions never need it). Row
    ``origin`` (the last) is the query's start point: its two slots are rewritten per search to
    point at the snapped segment's end nodes with the partial costs, so a route can start
    mid-segment without copying the matrix.
    """

    arcs: Arcs
    cost: Cost
    avoid: frozenset[str]
    seg_cost: np.ndarray
    weights: np.ndarray
    max_rate: float  # at least the most metres per unit of cost on any arc (top speed in m/s)
    total_cost: float  # of all allowed arcs: a bound beyond which a search is unbounded anyway
    version: int
    hierarchy: Hierarchy | None = None  # the shape's CCH, when the network is large enough
    lock: threading.Lock = field(default_factory=threading.Lock)
    _matrix: csr_matrix | None = None

    SLOTS = 2

    @property
    def hierarchy_key(self) -> tuple[Cost, frozenset[str]]:
        """Which of the hierarchy's metrics is this cost model's."""
        return self.cost, self.avoid

    @property
    def arc_costs(self) -> np.ndarray:
        """Cost of every arc (a view of ``weights`` without the origin slots)."""
        return self.weights[: -self.SLOTS]

    @property
    def origin(self) -> int:
        """Index of the virtual origin node (one past the last real node)."""
        return self.arcs.n_nodes

    @property
    def matrix(self) -> csr_matrix:
        """The Dijkstra CSR matrix (built on first use; it shares ``weights``)."""
        with self.lock:
            return self._csr()

    def matrix_unlocked(self) -> csr_matrix:
        """:attr:`matrix` for a caller that holds ``lock`` (searches from real nodes)."""
        return self._csr()

    def _csr(self) -> csr_matrix:
        if self._matrix is None:  # callers hold the lock
            n, pad = self.arcs.n_nodes, self.SLOTS
            indices = np.append(self.arcs.head, np.zeros(pad, np.uint32)).astype(np.int32)
            indptr = np.append(self.arcs.indptr, self.arcs.indptr[-1] + pad).astype(np.int32)
            self._matrix = csr_matrix((self.weights, indices, indptr), shape=(n + 1, n + 1))
        return self._matrix

    def fast_path(self, outs: Sequence[tuple[int, float]], ins: Sequence[tuple[int, float]]
                  ) -> tuple[int, int, np.ndarray, np.ndarray] | None:
        """Through the hierarchy: (departure index, arrival index, segment rows, directions)
        of the cheapest way, or ``None`` when the hierarchy cannot answer for this version
        (not built yet, superseded, or no path within its range): then search with Dijkstra."""
        metric = self.metric()
        found = metric.shortest(self.version, outs, ins) if metric is not None else None
        if found is None:
            return None
        i, j, arcs = found
        assert self.hierarchy is not None
        self.hierarchy.answered += 1
        return i, j, self.arcs.row[arcs], self.arcs.way[arcs]

    def answers_fast(self) -> bool:
        """Whether the hierarchy answers for this version now (no wait): a search is then
        a fraction of a millisecond whatever the network's size."""
        return self.hierarchy is not None and self.hierarchy.metric(
            self.hierarchy_key, self.version, self.arc_costs, self.max_rate) is not None

    def metric(self) -> Metric | None:
        """The hierarchy's metric for this cost model at this version, when it can answer
        (waiting briefly for an update that is bringing it here), else ``None``."""
        if self.hierarchy is None:
            return None
        wait = min(METRIC_WAIT_MAX_S, METRIC_WAIT_S_PER_ARC * len(self.arcs))
        return self.hierarchy.metric(self.hierarchy_key, self.version, self.arc_costs,
                                     self.max_rate, wait_s=wait)

    def search(self, departures: Iterable[tuple[int, float]],
               limit: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Dijkstra from the virtual origin: distances and predecessors of every node."""
        arcs = list(departures)[: self.SLOTS]
        arcs += [arcs[0]] * (self.SLOTS - len(arcs))
        with self.lock:
            matrix = self._csr()
            matrix.indices[-self.SLOTS:] = [node for node, _ in arcs]
            matrix.data[-self.SLOTS:] = [c for _, c in arcs]
            dist, pred = dijkstra(matrix, directed=True, indices=self.origin,
                                  return_predecessors=True, limit=limit)
        return dist, pred

    def path_arcs(self, nodes: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """(segment rows, directions) of the cheapest arcs joining consecutive graph nodes."""
        path = np.asarray(nodes, dtype=np.int64)
        arcs = self.arcs.cheapest(path[:-1], path[1:], self.weights)
        return self.arcs.row[arcs], self.arcs.way[arcs]

    @classmethod
    def build(cls, graph: RoadGraph, cost: Cost, avoid: frozenset[str]) -> CostGraph:
        """Every arc's weight under ``cost``, avoiding the classes ``avoid``."""
        arcs, s = graph.shape.arcs, graph.segs
        seg_cost = segment_costs(cost, s.length_m, graph.speed_kph)
        weights = np.append(_arc_costs(arcs, s, seg_cost, avoid), np.zeros(cls.SLOTS))
        cg = cls(arcs, cost, avoid, seg_cost, weights, 1.0, 0.0, graph.version,
                 hierarchy=graph.shape.hierarchy)
        cg.max_rate = _max_rate(arcs, s, cg.arc_costs)
        cg.total_cost = float(cg.arc_costs[np.isfinite(cg.arc_costs)].sum())
        if cg.hierarchy is not None:
            cg.hierarchy.metric(cg.hierarchy_key, cg.version, cg.arc_costs, cg.max_rate)
        return cg

    def patched(self, graph: RoadGraph, rows: np.ndarray) -> CostGraph:
        """This cost model on ``graph``, a later version of the same shape that differs at
        ``rows`` only: the weights of those rows' arcs are recomputed, everything else is
        shared or copied. The hierarchy's metric follows in the background
        (:meth:`Hierarchy.metric`); until it has, Dijkstra answers for this version."""
        s = graph.segs
        fresh = segment_costs(self.cost, s.length_m[rows], graph.speed_kph[rows])
        seg_cost = replaced(self.seg_cost, rows, fresh)
        touched = self.arcs.of_rows(rows)
        new = _arc_costs(self.arcs, s, seg_cost, self.avoid, touched)
        old = self.weights[touched]
        weights = self.weights.copy()  # never shared: each version's searches write its slots
        weights[touched] = new
        finite_new, finite_old = new[np.isfinite(new)], old[np.isfinite(old)]
        cg = replace(self, seg_cost=seg_cost, weights=weights, version=graph.version,
                     max_rate=max(self.max_rate, _max_rate(self.arcs, s, new, touched)),
                     total_cost=self.total_cost + float(finite_new.sum() - finite_old.sum()),
                     lock=threading.Lock(), _matrix=None)
        if cg.hierarchy is not None:  # starts the metric's update in the background
            cg.hierarchy.metric(cg.hierarchy_key, cg.version, cg.arc_costs, cg.max_rate)
        return cg


def _arc_costs(arcs: Arcs, s: Segments, seg_cost: np.ndarray, avoid: frozenset[str],
               which: np.ndarray | slice = slice(None)) -> np.ndarray:
    """Cost of the arcs ``which`` (all by default): their segment's cost, or infinity where
    the one-way rule forbids the direction or the road class is avoided."""
    row, way = arcs.row[which], arcs.way[which]
    ok = np.where(way > 0, s.oneway[row] >= 0, s.oneway[row] <= 0)
    if avoid:
        ok &= ~np.isin(s.road_class[row], list(avoid))
    return np.where(ok, seg_cost[row], np.inf)


def _max_rate(arcs: Arcs, s: Segments, costs: np.ndarray,
              which: np.ndarray | slice = slice(None)) -> float:
    """Most metres per unit of cost among arcs ``which`` with a finite positive cost."""
    priced = np.isfinite(costs) & (costs > 0)
    return float((s.length_m[arcs.row[which]][priced] / costs[priced]).max(initial=1.0))


@dataclass(frozen=True)
class Shape:
    """What a graph derives from segment ends and geometry, so an edit that keeps every
    segment's end nodes (attributes, or a geometry with the same ends: most edits) reuses the
    arcs and the hierarchy and patches the per-vertex and per-row geometry at its rows."""

    node_ids: np.ndarray
    u: np.ndarray  # node index of each segment's source
    v: np.ndarray  # ... and target
    arcs: Arcs
    fracs: np.ndarray  # metric fraction of each vertex along its segment
    bbox: np.ndarray  # (n, 4) per segment, column-major: patches test one column at a time
    bearing_start: np.ndarray  # compass bearing leaving the first vertex, forward
    bearing_end: np.ndarray  # ... and reaching the last
    hierarchy: Hierarchy | None  # built lazily in the background, shared while arcs stay

    @classmethod
    def of(cls, s: Segments, previous: Shape | None = None) -> Shape:
        """Node ids, arcs, end bearings and vertex fractions of the segments, computed once per
        graph so responses need no per-request geometry work.

        ``previous``: the shape this one replaces; its hierarchy is kept when the arcs are
        the same, and otherwise lends its node order so the new hierarchy builds in seconds
        (:class:`Hierarchy`)."""
        node_ids, inverse = np.unique(np.concatenate([s.source, s.target]), return_inverse=True)
        u, v = inverse[: len(s)].astype(np.int32), inverse[len(s):].astype(np.int32)
        same_arcs = previous is not None and np.array_equal(previous.node_ids, node_ids) and \
            np.array_equal(previous.u, u) and np.array_equal(previous.v, v)
        arcs = previous.arcs if same_arcs and previous is not None else \
            Arcs.of(u, v, len(node_ids))
        hierarchy = previous.hierarchy if same_arcs and previous is not None else None
        if hierarchy is None:
            hierarchy = _hierarchy(s, u, v, node_ids, arcs,
                                   previous.hierarchy if previous is not None else None)
        return cls(node_ids, u, v, arcs, _fractions(s), np.asfortranarray(s.bboxes()),
                   *_end_bearings(s), hierarchy)

    def spliced(self, layout: Layout, rows: np.ndarray, old: Segments, segs: Segments,
                fresh: Segments) -> Shape:
        """This shape after an edit that changed which segments join which nodes (a split,
        merge, segment added or deleted): ``rows`` of ``old`` gave way to ``fresh``, making
        ``segs``. Node indices and arcs are renumbered and patched rather than sorted anew,
        per-row geometry is laid out around the fresh rows, and a new hierarchy is made (built
        in the previous one's node order)."""
        n = len(self.node_ids)
        degree = np.bincount(self.u, minlength=n) + np.bincount(self.v, minlength=n)
        gone = np.concatenate([self.u[rows], self.v[rows]])
        np.subtract.at(degree, gone, 1)
        ends = np.unique(np.concatenate([fresh.source, fresh.target]))
        at = np.minimum(np.searchsorted(self.node_ids, ends), max(n - 1, 0))
        known = self.node_ids[at] == ends if n else np.zeros(len(ends), bool)
        orphan = np.unique(gone[degree[gone] == 0])
        orphan = orphan[~np.isin(self.node_ids[orphan], ends)]
        added = ends[~known]
        kept = np.delete(self.node_ids, orphan)
        node_ids = np.insert(kept, np.searchsorted(kept, added), added)
        everyone = np.arange(n)
        node_map = (everyone - np.searchsorted(orphan, everyone)
                    + np.searchsorted(added, self.node_ids))
        u = layout.join(node_map[self.u], np.searchsorted(node_ids, fresh.source))
        v = layout.join(node_map[self.v], np.searchsorted(node_ids, fresh.target))
        u, v = u.astype(np.int32), v.astype(np.int32)
        row_map, fresh_rows = layout.row_maps()
        arcs = self.arcs.spliced(row_map, node_map, len(node_ids), len(segs), fresh_rows,
                                 u[fresh_rows], v[fresh_rows])
        fracs = layout.join_ragged(old.offsets, self.fracs, fresh.offsets, _fractions(fresh))[1]
        start, end = _end_bearings(fresh)
        return Shape(node_ids, u, v, arcs, fracs,
                     np.asfortranarray(layout.join(self.bbox, fresh.bboxes())),
                     layout.join(self.bearing_start, start), layout.join(self.bearing_end, end),
                     _hierarchy(segs, u, v, node_ids, arcs, self.hierarchy))

    def replaced(self, rows: np.ndarray, old: Segments, fresh: Segments) -> Shape:
        """This shape after ``rows`` of ``old`` became ``fresh`` with the same end nodes: the
        arcs and hierarchy stay, the geometry of those rows is patched."""
        _, fracs = spliced(old.offsets, self.fracs, rows, fresh.offsets, _fractions(fresh))
        start, end = _end_bearings(fresh)
        return replace(self, fracs=fracs, bbox=replaced(self.bbox, rows, fresh.bboxes()),
                       bearing_start=replaced(self.bearing_start, rows, start),
                       bearing_end=replaced(self.bearing_end, rows, end))


def _fractions(s: Segments) -> np.ndarray:
    """Metric fraction of each vertex along its segment."""
    return vertex_fractions(s.coords, s.offsets) if len(s) else np.zeros(0)


def _hierarchy(s: Segments, u: np.ndarray, v: np.ndarray, node_ids: np.ndarray, arcs: Arcs,
               previous: Hierarchy | None) -> Hierarchy | None:
    """A new (not yet built) hierarchy for these arcs, when the network is large enough."""
    if len(s) < max(1, routing_settings().hierarchy_min_segments):
        return None
    lonlat = np.zeros((len(node_ids), 2))
    lonlat[u], lonlat[v] = s.coords[s.offsets[:-1]], s.coords[s.offsets[1:] - 1]
    return Hierarchy(arcs, lonlat, node_ids, previous)


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
    shape: Shape = None  # type: ignore[assignment]  # derived from segs unless given
    speed_kph: np.ndarray = None  # type: ignore[assignment]  # effective speed per row
    _costs: dict[tuple[Cost, frozenset[str]], CostGraph] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _index: SegmentIndex | None = None

    def __post_init__(self) -> None:
        shape = self.shape = self.shape or Shape.of(self.segs)
        self.node_ids, self.u, self.v, self.fracs = shape.node_ids, shape.u, shape.v, shape.fracs
        self.bbox, self.bearing_start, self.bearing_end = (shape.bbox, shape.bearing_start,
                                                           shape.bearing_end)
        if self.speed_kph is None:
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

    @property
    def index(self) -> SegmentIndex:
        """The spatial index snapping searches (built on first use, then carried over to
        later versions by :meth:`patched`)."""
        with self._lock:
            if self._index is None:
                self._index = SegmentIndex.of(self)
            return self._index

    def built(self, cost: Cost, avoid: frozenset[str]) -> CostGraph | None:
        """The cost graph of ``(cost, avoid)`` if it is built and the snapping index too;
        ``None`` when a request would build either first."""
        with self._lock:
            return self._costs.get((cost, avoid)) if self._index is not None else None

    def _carry_index(self, graph: RoadGraph, changed: np.ndarray) -> RoadGraph:
        """``graph`` (the next version, where segments ``changed`` were added or edited) with
        this version's spatial index carried over."""
        with self._lock:
            index = self._index
        graph._index = index.after(changed, len(graph.segs)) if index is not None else None
        return graph

    def costs(self, cost: Cost, avoid: frozenset[str] = DEFAULT.forbidden) -> CostGraph:
        """The cost graph for a cost model and avoided road classes (a few kept, LRU); by
        default the one a request naming no profile and no avoid= routes on."""
        key = (cost, avoid)
        with self._lock:
            cg = self._costs.pop(key, None) or CostGraph.build(self, cost, avoid)
            self._costs[key] = cg  # most recently used last
            while len(self._costs) > MAX_COST_GRAPHS:
                del self._costs[next(iter(self._costs))]
            return cg

    def patched(self, version: int, box: Sequence[float], fresh: Segments) -> RoadGraph:
        """A new graph where every segment inside ``box`` is replaced by ``fresh``.

        ``fresh`` holds the current rows of the segments whose geometry meets ``box``; any
        graph segment meeting it that is not in ``fresh`` was deleted (its old geometry is
        part of the box the database announced). When the same segments keep the same end
        nodes, only those rows are patched, and every cost model already built is carried
        over patched, so the new version serves at once (:meth:`CostGraph.patched`).
        """
        minx, miny, maxx, maxy = box
        b = self.bbox
        inside = (b[:, 0] <= maxx) & (b[:, 2] >= minx) & (b[:, 1] <= maxy) & (b[:, 3] >= miny)
        k = np.minimum(np.searchsorted(self.segs.ids, fresh.ids), max(len(self.segs) - 1, 0))
        if len(self.segs):
            inside[k[self.segs.ids[k] == fresh.ids]] = True
        rows = np.flatnonzero(inside)
        if not self._same_ends(rows, fresh):
            return self._carry_index(self._respliced(version, rows, fresh), fresh.ids)
        fresh_speed = effective_speed_kph(fresh.speed_limit, fresh.road_class)
        graph = RoadGraph(self.network_id, version, self.segs.replaced(rows, fresh),
                          shape=self.shape.replaced(rows, self.segs, fresh),
                          speed_kph=replaced(self.speed_kph, rows, fresh_speed))
        with self._lock:
            carried = list(self._costs.items())
        graph._costs = {key: cg.patched(graph, rows) for key, cg in carried}
        return self._carry_index(graph, fresh.ids)

    def _respliced(self, version: int, rows: np.ndarray, fresh: Segments) -> RoadGraph:
        """A new graph where ``rows`` gave way to ``fresh`` and the arcs changed: laid out from
        this one's arrays around the fresh rows (a large edit rebuilds instead). Cost models
        are rebuilt on first use; the hierarchy is rebuilt in the background."""
        if len(rows) + len(fresh) > SPLICE_MAX_ROWS or not len(self.segs):
            keep = np.ones(len(self.segs), bool)
            keep[rows] = False
            segs = self.segs.take(np.flatnonzero(keep)).concat(fresh)
            return RoadGraph(self.network_id, version, segs, shape=Shape.of(segs, self.shape))
        layout = Layout.of(self.segs.ids, rows, fresh.ids)
        segs = self.segs.spliced(layout, fresh)
        speed = layout.join(self.speed_kph,
                            effective_speed_kph(fresh.speed_limit, fresh.road_class))
        return RoadGraph(self.network_id, version, segs, speed_kph=speed,
                         shape=self.shape.spliced(layout, rows, self.segs, segs, fresh))

    def _same_ends(self, rows: np.ndarray, fresh: Segments) -> bool:
        """True when ``fresh`` are exactly the segments at ``rows`` with the same end nodes:
        the arcs are unchanged, only weights and geometry may differ."""
        old = self.segs
        return (np.array_equal(old.ids[rows], fresh.ids)
                and np.array_equal(old.source[rows], fresh.source)
                and np.array_equal(old.target[rows], fresh.target))
