"""Customizable contraction hierarchies (CCH) over a road graph, kept exact under live edits.

Why a CCH: on a million segments one Dijkstra touches a large share of the graph for every
route (~100 ms compiled, ~1.8 s in ``pgr_dijkstra``). A CCH splits the work in three:
a *topology* (nested-dissection order + chordal supergraph; seconds, depends only on which
arcs exist), a *metric* (the arc weights pushed up the hierarchy; seconds once, then
per changed arc from milliseconds for a side street to ~1 s for a motorway on a million
segments, as a change reaches every shortcut over it), and *queries* (elimination-tree
searches; milliseconds).
RoutingKit, through ``pyroutingkit``, does all three in compiled code without holding the GIL.

Edits keep routes exact without any admissibility rule, because every edit that leaves the set
of arcs alone is a *weight* change: speed limit, class, length, one-way rules and avoided
classes are all weights here (each segment contributes both directions as arcs; a forbidden
direction weighs :data:`pyroutingkit.INF_WEIGHT`). Such an edit updates the metric partially,
in the background: a metric answers only for the exact graph version it was brought to, and
routes on a newer version use the exact Dijkstra meanwhile, so the next route sees the edit
whether the road got faster, slower, closed or one-way. An edit that changes the arcs (a segment
added, split, merged, or moved to other nodes) needs a new topology: that is rebuilt in a
background thread from the previous contraction order (seconds, :mod:`app.routing.orders`)
and, until it is ready, routes use the exact compiled Dijkstra of :mod:`app.routing.graph`
(never a stale hierarchy).

Weights are integers: costs are quantised to ``quantum`` (:func:`quantum_for`), so among paths
whose costs differ by less than ``quantum`` per arc the search may pick either; the route's
reported weight is always the float sum of its segments' costs.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass, field

import numpy as np
import pyroutingkit as rk

from app.routing import orders
from app.routing.arcs import Arcs
from app.routing.geometry import haversine_m

log = logging.getLogger("ugvmap.routing")

INF = rk.INF_WEIGHT
HEADROOM = 2**29  # largest quantised route cost we rely on (INF is 2**31 - 1)
DETOUR = 8.0  # a shortest path is assumed at most this many times the network's diagonal
PARTIAL_LIMIT = 50_000  # changed arcs beyond which a full customisation is cheaper
MAX_METRICS = 3  # per hierarchy (cost model x avoid set), least recently used dropped


def quantum_for(node_lonlat: np.ndarray, max_rate: float) -> float:
    """Cost units per integer weight step: fine enough that routes up to ``DETOUR`` times the
    network's diagonal stay below :data:`HEADROOM` (a longer one comes back infinite and
    falls back to the exact search)."""
    lo, hi = node_lonlat.min(axis=0), node_lonlat.max(axis=0)
    diagonal = max(1.0, float(haversine_m((lo[0], lo[1]), (hi[0], hi[1]))))
    return DETOUR * diagonal / max_rate / HEADROOM


def quantise(costs: np.ndarray, quantum: float) -> np.ndarray:
    """Integer weights (RoutingKit's are uint32): ``INF`` for a forbidden direction, capped
    just below it otherwise so a long but allowed arc is never taken for a closed one."""
    q = np.rint(costs / quantum)
    return np.where(np.isfinite(q), np.minimum(q, INF - 1), INF).astype(np.uint32)


UPDATING = -1  # a metric's version while its weights are being changed


@dataclass
class Metric:
    """One cost model's customisation, at the newest graph version it was brought to.

    ``version`` is :data:`UPDATING` while a background update changes the weights, so no query
    sees half-propagated weights; ``target`` (with ``target_costs``) is the newest version the
    metric has been asked to reach.
    """

    cch: rk.CCHMetric
    weights: np.ndarray  # uint32 per arc, as customised
    version: int
    quantum: float
    target: int = 0
    target_costs: np.ndarray | None = None
    syncing: bool = False  # an update is queued or running
    lock: threading.Lock = field(default_factory=threading.Lock)  # queries vs. version changes
    synced: threading.Condition = field(default_factory=threading.Condition)

    def __post_init__(self) -> None:
        self.target = self.version

    def shortest(self, version: int, outs: Sequence[tuple[int, float]],
                 ins: Sequence[tuple[int, float]]) -> tuple[int, int, np.ndarray] | None:
        """(index into ``outs``, index into ``ins``, input arc ids) of the cheapest way from
        any departure (node, cost) to any arrival; ``None`` when this metric is not at
        ``version`` or no path lies within the quantised range (the caller then runs the exact
        search, which also tells "no route" apart)."""
        if self.version != version:  # checked again under the lock
            return None
        with self.lock:
            if self.version != version:
                return None
            src = np.array([n for n, _ in outs], np.uint32)
            dst = np.array([n for n, _ in ins], np.uint32)
            i = j = 0
            if len(src) > 1 or len(dst) > 1:
                d = self.cch.distances_many_to_many(src, dst).astype(np.float64)
                d[d >= INF] = np.inf
                total = (np.array([c for _, c in outs])[:, None] + d * self.quantum
                         + np.array([c for _, c in ins])[None, :])
                i, j = (int(k) for k in np.unravel_index(int(np.argmin(total)), total.shape))
                if not np.isfinite(total[i, j]):
                    return None
            distance, _, arcs = self.cch.query(int(src[i]), int(dst[j]))
        if distance >= INF:
            return None
        return int(i), int(j), np.asarray(arcs, dtype=np.int64)

    def many_to_many(self, version: int, sources: np.ndarray, targets: np.ndarray
                     ) -> np.ndarray | None:
        """Costs from every node of ``sources`` to every node of ``targets`` (inf where none
        lies within the quantised range), or ``None`` when this metric is not at ``version``."""
        with self.lock:
            if self.version != version:
                return None
            d = self.cch.distances_many_to_many(sources.astype(np.uint32),
                                                targets.astype(np.uint32)).astype(np.float64)
        d[d >= INF] = np.inf
        return d * self.quantum

    def sync(self, target: int, arc_costs: np.ndarray) -> None:
        """Bring the weights to ``arc_costs`` (version ``target``) by partial customisation of
        the arcs whose quantised weight changed; queries are turned away meanwhile."""
        weights = quantise(arc_costs, self.quantum)
        changed = np.flatnonzero(self.weights != weights)
        with self.lock:  # waits for queries in flight; later ones see UPDATING
            self.version = UPDATING
        try:
            if len(changed) > PARTIAL_LIMIT:
                self.cch.customize(weights)
            elif len(changed):
                self.cch.update_weights(changed.astype(np.uint32), weights[changed])
            self.weights = weights
        finally:
            with self.lock:
                self.version = target if self.weights is weights else UPDATING
            with self.synced:
                self.synced.notify_all()


class Hierarchy:
    """The CCH topology of one graph *shape* (node set and arcs) and its metrics.

    Graph versions that share a shape share the hierarchy. The topology and each metric's
    first customisation are built by one background thread; later versions update a metric in
    place (:meth:`metric`), and a query from an older version than the metric's falls back to
    Dijkstra. The topology's contraction order comes from disk when these exact arcs were
    contracted before, else from ``previous`` (the hierarchy of the shape this one replaces)
    when few nodes are new, else from nested dissection (:mod:`app.routing.orders`).
    """

    def __init__(self, arcs: Arcs, node_lonlat: np.ndarray, node_ids: np.ndarray,
                 previous: Hierarchy | None = None) -> None:
        self.arcs = arcs
        self.node_lonlat = node_lonlat
        self.node_ids = node_ids
        self.topology: rk.CCHTopology | None = None
        self.order: orders.Order | None = None  # once built
        self.order_source = ""  # "saved", "derived" or "dissected", once built (logs, tests)
        self.ready = threading.Event()  # topology built (or failed)
        self._metrics: OrderedDict[object, Metric] = OrderedDict()
        self._pending: set[object] = set()
        self._scheduled = False
        self._lock = threading.Lock()
        self.answered = 0  # routes found through the hierarchy (logs, tests)
        # Where a derived order would come from: a built order, or a hierarchy queued for
        # building (never one that nobody asked for, so no chain of topologies stays alive).
        self._previous: orders.Order | Hierarchy | None = None
        self._superseded = False
        if previous is not None:
            self._previous = previous.order or (previous if previous._scheduled
                                                else previous._previous)
            previous._superseded = True

    def _previous_order(self) -> orders.Order | None:
        previous = self._previous
        while isinstance(previous, Hierarchy):
            previous.ready.wait()  # queued before us on the same thread: already done
            previous = previous.order or previous._previous
        return previous

    def build(self) -> None:
        """Build the topology now (the background thread does, when a query first asks): from
        a known order when there is one (seconds), else by nested dissection (minutes on a
        country); no GIL held either way. A hierarchy already replaced by a newer shape's
        before its turn came is skipped: one edit of several statements announces
        intermediate shapes that no route will ever use."""
        try:
            if self._superseded:
                return
            digest = orders.arcs_digest(self.node_ids, self.arcs)
            previous = self._previous_order()
            from_previous = orders.derived(previous, self.node_ids) if previous else None
            with orders.dissecting(digest) if from_previous is None else nullcontext():
                known = orders.saved(digest, self.node_ids)
                if known is not None:
                    rank, added, self.order_source = (
                        np.searchsorted(self.node_ids, known.node_ids), known.added, "saved")
                elif from_previous is not None:
                    (rank, added), self.order_source = from_previous, "derived"
                else:
                    topology = rk.CCHTopology()
                    topology.build(self.arcs.tail, self.arcs.head,
                                   self.node_lonlat[:, 1].astype(np.float32),
                                   self.node_lonlat[:, 0].astype(np.float32),
                                   len(self.node_lonlat))
                    rank, added, self.order_source = orders.order_of(topology), 0, "dissected"
                    orders.save(digest, rank, added)
            if self.order_source != "dissected":
                topology = orders.topology_from(self.arcs, rank)
            if self.order_source == "derived":
                orders.save(digest, rank, added)
            self.order = orders.Order(self.node_ids[rank], added)
            self.topology = topology
            self._previous = None
        except Exception:  # the exact search keeps serving; say why once
            log.exception("building the routing hierarchy failed; using Dijkstra")
        finally:
            self.ready.set()

    def _customize(self, key: object, version: int, arc_costs: np.ndarray,
                   max_rate: float) -> None:
        try:
            quantum = quantum_for(self.node_lonlat, max_rate)
            weights = quantise(arc_costs, quantum)
            cch = rk.CCHMetric(self.topology)
            cch.customize(weights)
            with self._lock:
                self._metrics[key] = Metric(cch, weights, version, quantum)
                while len(self._metrics) > MAX_METRICS:
                    self._metrics.popitem(last=False)
        except Exception:
            log.exception("customising the routing hierarchy failed; using Dijkstra")
        finally:
            with self._lock:
                self._pending.discard(key)

    def metric(self, key: object, version: int, arc_costs: np.ndarray, max_rate: float,
               wait_s: float = 0.0) -> Metric | None:
        """The metric for ``key`` if it is at ``version``, else ``None`` (use Dijkstra).

        Everything slow happens in the background: the topology, each metric's first
        customisation, and bringing a metric to a newer version by partial customisation of
        the arcs whose weight changed (milliseconds for a side street, up to a second for a
        motorway on a million segments: a change propagates to every shortcut over it). A
        graph version is therefore published without waiting for its metric; until the metric
        has reached it, its routes come from the exact Dijkstra. ``wait_s``: how long a query
        may wait for an update that is bringing the metric to its version, when that is
        likely sooner than a Dijkstra search."""
        with self._lock:
            if self.topology is None:
                if not self._scheduled:
                    self._scheduled = True
                    _background.submit(self.build)
                return None
            current = self._metrics.get(key)
            if current is None:
                if key not in self._pending:
                    self._pending.add(key)
                    _background.submit(self._customize, key, version, arc_costs, max_rate)
                return None
            self._metrics.move_to_end(key)
            if current.target < version:
                current.target, current.target_costs = version, arc_costs
                if not current.syncing:
                    current.syncing = True
                    _updates.submit(self._follow, current)
            elif current.target > version:
                return None
        if current.version != version and wait_s > 0:
            with current.synced:
                current.synced.wait_for(lambda: current.version == version
                                        or current.target != version, wait_s)
        return current if current.version == version else None

    def _follow(self, metric: Metric) -> None:
        """Update ``metric`` until it reaches its newest target (edits coalesce)."""
        while True:
            with self._lock:
                target, costs = metric.target, metric.target_costs
                if metric.version == target or costs is None:
                    metric.syncing, metric.target_costs = False, None
                    return
            try:
                metric.sync(target, costs)
            except Exception:
                log.exception("updating the routing hierarchy failed; using Dijkstra")
                with self._lock:  # drop it: the next query customises afresh
                    metric.syncing = False
                    for key in [k for k, m in self._metrics.items() if m is metric]:
                        del self._metrics[key]
                return


_background = ThreadPoolExecutor(max_workers=1, thread_name_prefix="routing-hierarchy")
# Metric updates get their own thread: a topology build on the other one can take minutes.
_updates = ThreadPoolExecutor(max_workers=1, thread_name_prefix="routing-metric")
