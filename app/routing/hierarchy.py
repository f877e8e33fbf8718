"""Customizable contraction hierarchies (CCH) over a road graph, kept exact under live edits.

Why a CCH: on a million segments one Dijkstra touches a large share of the graph for every
route (~100 ms compiled, ~1.8 s in ``pgr_dijkstra``). A CCH splits the work in three:
a *topology* (nested-dissection order + chordal supergraph; seconds, depends only on which
arcs exist), a *metric* (the arc weights pushed up the hierarchy; seconds once, then
milliseconds per changed arc), and *queries* (elimination-tree searches; milliseconds).
RoutingKit, through ``pyroutingkit``, does all three in compiled code without holding the GIL.

Edits keep routes exact without any admissibility rule, because every edit that leaves the set
of arcs alone is a *weight* change: speed limit, class, length, one-way rules and avoided
classes are all weights here (each segment contributes both directions as arcs; a forbidden
direction weighs :data:`pyroutingkit.INF_WEIGHT`). Such an edit updates the metric partially
before the graph version that contains it is published, so the next route sees it whether
the road got faster, slower, closed or one-way. An edit that changes the arcs (a segment
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


@dataclass
class Metric:
    """One cost model's customisation, owned by the newest graph version that updated it."""

    cch: rk.CCHMetric
    weights: np.ndarray  # uint32 per arc, as customised
    version: int
    quantum: float
    lock: threading.Lock = field(default_factory=threading.Lock)

    def shortest(self, version: int, outs: Sequence[tuple[int, float]],
                 ins: Sequence[tuple[int, float]]) -> tuple[int, int, np.ndarray] | None:
        """(index into ``outs``, index into ``ins``, input arc ids) of the cheapest way from
        any departure (node, cost) to any arrival; ``None`` when this metric no longer is at
        ``version`` or no path lies within the quantised range (the caller then runs the exact
        search, which also tells "no route" apart)."""
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
        # Where a derived order would come from: a built order, or a hierarchy still queued
        # for building (never one that nobody asked for, so no chain of topologies stays alive).
        self._previous: orders.Order | Hierarchy | None = None
        if previous is not None:
            self._previous = previous.order or (previous if previous._scheduled
                                                else previous._previous)

    def _previous_order(self) -> orders.Order | None:
        previous = self._previous
        if isinstance(previous, Hierarchy):
            previous.ready.wait()  # queued before us on the same thread: already done
            previous = previous.order
        return previous

    def _build(self) -> None:
        """The topology, from a known order when there is one (seconds), else by nested
        dissection (minutes on a country); no GIL held either way."""
        try:
            digest = orders.arcs_digest(self.node_ids, self.arcs)
            known = orders.saved(digest, self.node_ids)
            previous = self._previous_order() if known is None else None
            from_previous = orders.derived(previous, self.node_ids) if previous else None
            if known is not None:
                rank = np.searchsorted(self.node_ids, known.node_ids)
                topology, added, self.order_source = (orders.topology_from(self.arcs, rank),
                                                      known.added, "saved")
            elif from_previous is not None:
                rank, added = from_previous
                topology = orders.topology_from(self.arcs, rank)
                self.order_source = "derived"
            else:
                topology = rk.CCHTopology()
                topology.build(self.arcs.tail, self.arcs.head,
                               self.node_lonlat[:, 1].astype(np.float32),
                               self.node_lonlat[:, 0].astype(np.float32), len(self.node_lonlat))
                rank, added, self.order_source = orders.order_of(topology), 0, "dissected"
            if self.order_source != "saved":
                orders.save(digest, rank, added)
            self.order = orders.Order(self.node_ids[rank], added)
            self.topology = topology
        except Exception:  # the exact search keeps serving; say why once
            log.exception("building the routing hierarchy failed; using Dijkstra")
        finally:
            self._previous = None
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
               changed: tuple[int, np.ndarray] | None = None) -> Metric | None:
        """The metric for ``key`` at ``version``, or ``None`` (use Dijkstra) while the topology
        or the metric's first customisation is being built in the background, or when a newer
        version already owns the metric. A metric at an older version is brought to
        ``version`` here by partial customisation of the arcs whose weight changed
        (milliseconds), so it is exact for this version before the call returns.

        ``changed``: (since, arcs): only ``arcs`` differ from version ``since``; when the
        metric is at ``since`` only they are compared, not every arc of the network."""
        with self._lock:
            if self.topology is None:
                if not self._scheduled:
                    self._scheduled = True
                    _background.submit(self._build)
                return None
            current = self._metrics.get(key)
            if current is None:
                if key not in self._pending:
                    self._pending.add(key)
                    _background.submit(self._customize, key, version, arc_costs, max_rate)
                return None
            self._metrics.move_to_end(key)
            if current.version >= version:
                return current if current.version == version else None
            with current.lock:
                if changed is not None and changed[0] == current.version:
                    arcs = changed[1]
                    weights = quantise(arc_costs[arcs], current.quantum)
                    differ = current.weights[arcs] != weights
                    arcs, weights = arcs[differ], weights[differ]
                else:
                    weights = quantise(arc_costs, current.quantum)
                    arcs = np.flatnonzero(current.weights != weights)
                    weights = weights[arcs]
                if len(arcs) > PARTIAL_LIMIT:
                    current.weights[arcs] = weights
                    current.cch.customize(current.weights)
                elif len(arcs):
                    current.cch.update_weights(arcs.astype(np.uint32), weights)
                    current.weights[arcs] = weights
                current.version = version
            return current


_background = ThreadPoolExecutor(max_workers=1, thread_name_prefix="routing-hierarchy")
