"""Graphs kept current in every worker process: load once, then follow LISTEN/NOTIFY.

Each process follows channel ``network_changed`` (sent by the trigger of migration
``0002_network_change_notify`` when an edit commits) through its shared listener,
:mod:`app.db.notify`. A notification whose version
directly follows the graph's patches just the announced bounding box; a gap (missed
notification, reconnect) reloads the network. Requests add a stronger guarantee: the snap query
reads ``networks.version`` and :meth:`GraphRegistry.get` waits until the graph has caught up
(as long as the listener makes progress; a reload only when it stalls), so an edit is visible
to the very next route query in any worker.
"""

from __future__ import annotations

import logging
import threading
import time
from functools import partial

import psycopg

from app.db.notify import Subscriber, network_changes
from app.db.session import libpq_dsn
from app.errors import DatabaseUnavailableError
from app.routing.costs import Cost
from app.routing.graph import SEGMENT_COLUMNS, RoadGraph, Segments, Shape

log = logging.getLogger("ugvmap.routing")

# Box edges are widened by this much (degrees, ~1 cm) so float rounding never drops a segment.
BOX_EPS = 1e-7
# A request whose graph is behind waits while the listener makes progress (one edit of
# several statements is several versions; a topology patch of a big network takes a second);
# it reloads when nothing moved for CATCH_UP_TIMEOUT_S, or after CATCH_UP_LIMIT_S in all.
CATCH_UP_TIMEOUT_S = 2.0
CATCH_UP_LIMIT_S = 30.0



def read_segments(conn: psycopg.Connection, network_id: int,
                  box: list[float] | None = None) -> tuple[Segments, int]:
    """Segments (all, or those meeting ``box``) and the network version, in one snapshot."""
    with conn.transaction():
        conn.execute("SET TRANSACTION ISOLATION LEVEL REPEATABLE READ")
        row = conn.execute("SELECT version FROM networks WHERE id = %s", (network_id,)).fetchone()
        if row is None:
            return Segments.from_rows([]), -1
        sql = f"SELECT {SEGMENT_COLUMNS} FROM road_segments WHERE network_id = %s"
        params: tuple = (network_id,)
        if box is not None:  # by the GiST index, never by network_id's: after a bulk load its
            # statistics may say "a few rows", and the planner would scan the whole network
            sql = (f"SELECT {SEGMENT_COLUMNS} FROM road_segments WHERE network_id + 0 = %s "
                   "AND geom && ST_MakeEnvelope(%s, %s, %s, %s, 4326)")
            params += (box[0] - BOX_EPS, box[1] - BOX_EPS, box[2] + BOX_EPS, box[3] + BOX_EPS)
        rows = conn.execute(sql, params, binary=True).fetchall()
    return Segments.from_rows(rows), int(row[0])


class GraphRegistry:
    """The graphs of one database, shared by all request threads of a process."""

    def __init__(self, database_url: str) -> None:
        self._dsn = libpq_dsn(database_url)
        self._graphs: dict[int, RoadGraph] = {}
        self._changed = threading.Condition()
        self._update = threading.RLock()  # one writer at a time: loads and patches
        self._database_url = database_url
        self._subscribed = False
        self._reader: psycopg.Connection | None = None  # the listener's, under _update
        self._applying: int | None = None  # network the listener is patching right now
        # For logs and tests: patches should dominate; "waited": requests that outwaited the
        # catch-up timeout and found the listener's patch done instead of reloading.
        self.stats = {"loads": 0, "patches": 0, "waited": 0}

    # -- queries -------------------------------------------------------------------------
    def get(self, network_id: int, min_version: int) -> RoadGraph:
        """The network's graph, at ``min_version`` or later (loading it the first time)."""
        self._ensure_listener()
        graph = self._graphs.get(network_id)
        if graph is None:
            return self._reload(network_id)
        give_up = time.monotonic() + CATCH_UP_LIMIT_S
        while graph.version < min_version:  # the listener is normally milliseconds behind
            seen = graph.version
            with self._changed:
                self._changed.wait_for(partial(self._moved, network_id, seen),
                                       CATCH_UP_TIMEOUT_S)
            graph = self._graphs[network_id]
            stalled = graph.version == seen and self._applying != network_id
            if graph.version < min_version and (stalled or time.monotonic() > give_up):
                return self._reload(network_id, min_version)  # a notification was lost
        return graph

    def current(self, network_id: int, min_version: int) -> RoadGraph | None:
        """The network's graph if it is loaded and at ``min_version`` or later; ``None`` when
        :meth:`get` would have to wait for the listener or load it."""
        graph = self._graphs.get(network_id)
        return graph if graph is not None and graph.version >= min_version else None

    def _moved(self, network_id: int, seen: int) -> bool:
        return self._graphs[network_id].version > seen

    def _reload(self, network_id: int, min_version: int | None = None) -> RoadGraph:
        try:
            return self._load(network_id, min_version)
        except psycopg.OperationalError as exc:
            raise DatabaseUnavailableError(f"cannot load the road graph: {exc}") from exc

    def _load(self, network_id: int, min_version: int | None = None) -> RoadGraph:
        """Read the whole network, unless (once the update lock is ours) the graph already is
        at ``min_version``: a request that gave up waiting while the listener was applying a
        slow patch (a topology change on a big network) takes that patch, not a reload."""
        with self._update:
            current = self._graphs.get(network_id)
            if current is not None and min_version is not None and current.version >= min_version:
                self.stats["waited"] += 1
                return current
            with psycopg.connect(self._dsn) as conn:
                segs, version = read_segments(conn, network_id)
            current = self._graphs.get(network_id)
            if current is not None and current.version >= version:
                return current
            graph = RoadGraph(network_id, version, segs, shape=Shape.of(segs, current.shape)) \
                if current else RoadGraph(network_id, version, segs)
            self._publish(graph)
            self.stats["loads"] += 1
        return graph

    def _publish(self, graph: RoadGraph) -> None:
        graph.costs(Cost.TIME)  # warm the default cost model off the request path
        _ = graph.index  # ... and the snapping index (carried over by patches)
        with self._changed:
            self._graphs[graph.network_id] = graph
            self._changed.notify_all()

    # -- listening -----------------------------------------------------------------------
    def _ensure_listener(self) -> None:
        # LISTEN must be in place before a graph's snapshot is read, or an edit committed in
        # between would never be announced to us (network_changes waits for it).
        if not self._subscribed:
            with self._update:
                if not self._subscribed:
                    self._subscribed = True
                    network_changes(self._database_url, Subscriber(
                        on_note=self._apply, on_connect=self._resync, on_disconnect=_fallback),
                        wait_s=CATCH_UP_TIMEOUT_S)

    def _resync(self) -> None:
        """After (re)connecting, reload any graph whose network moved while we were away."""
        if not self._graphs:
            return
        with psycopg.connect(self._dsn, autocommit=True) as conn:
            rows = conn.execute("SELECT id, version FROM networks WHERE id = ANY(%s)",
                                (list(self._graphs),)).fetchall()
        for net_id, version in rows:
            if self._graphs[net_id].version != version:
                self._load(net_id)

    def _read_box(self, net_id: int, box: list[float]) -> Segments:
        """The segments meeting ``box``, on a connection kept for the listener's reads (a new
        connection per edit costs more than the read); one reconnect if it broke."""
        if self._reader is not None and not self._reader.closed:
            try:
                return read_segments(self._reader, net_id, box)[0]
            except psycopg.OperationalError:
                self._reader.close()
        self._reader = psycopg.connect(self._dsn)
        return read_segments(self._reader, net_id, box)[0]

    def _apply(self, note: dict) -> None:
        net_id, version, box = note["network_id"], note["version"], note.get("bbox")
        if note.get("deleted"):  # ugvmap network delete: nothing left to route on
            with self._update, self._changed:
                self._graphs.pop(net_id, None)
            return
        # Under the update lock: a first load in progress finishes (and publishes) before this
        # note is judged, so a change committed during that load is patched, not dropped.
        with self._update:
            graph = self._graphs.get(net_id)
            if graph is None or version <= graph.version:
                return
            if version != graph.version + 1 or box is None:
                self._load(net_id)
                return
            self._applying = net_id
            try:
                fresh = self._read_box(net_id, box)
                wide = [box[0] - BOX_EPS, box[1] - BOX_EPS, box[2] + BOX_EPS, box[3] + BOX_EPS]
                self._publish(graph.patched(version, wide, fresh))
            finally:
                self._applying = None
            self.stats["patches"] += 1


_registries: dict[str, GraphRegistry] = {}
_registries_lock = threading.Lock()


def _fallback() -> None:
    """While disconnected, requests rely on the snap query's version check (``get`` waits
    for, then reloads, a graph older than the version the database reports)."""
    log.debug("routing graphs follow the per-request version check until reconnected")


def registry(database_url: str) -> GraphRegistry:
    """The process-wide registry for a database."""
    with _registries_lock:
        if database_url not in _registries:
            _registries[database_url] = GraphRegistry(database_url)
        return _registries[database_url]
