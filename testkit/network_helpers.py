"""Shared helpers for the network tests and benchmarks: a small synthetic network with known
answers, API tokens for each role, a wait for this process's change listener, and node
pairs that have a route."""

from __future__ import annotations

import random
import threading
import uuid
from typing import Any

import psycopg

from app.db.notify import Subscriber, network_changes
from app.db.session import session_scope
from app.network.tokens import create_token
from ingest.network import ImportSummary, RoadAttributes, RoadLine, write_network


def grid_network(name: str | None = None, attrs: dict[str, Any] | None = None
                 ) -> ImportSummary:
    """A 3x3 street grid around (10.0, 50.0): 6 straight streets of 2 blocks, noded into
    12 segments that meet at 9 nodes; every segment two lanes each way at 50 km/h, with
    ``attrs`` (e.g. ``{"extracted_from": layer}``, as road extraction writes)."""
    name = name or f"grid-{uuid.uuid4().hex[:8]}"
    step = 0.001
    lines = []
    for i in range(3):
        lines.append(RoadLine([(10.0, 50.0 + i * step), (10.0 + 2 * step, 50.0 + i * step)],
                              RoadAttributes(2, 2, 50.0, road_class="residential",
                                             name=f"Row {i}", attrs=dict(attrs or {}))))
        lines.append(RoadLine([(10.0 + i * step, 50.0), (10.0 + i * step, 50.0 + 2 * step)],
                              RoadAttributes(2, 2, 50.0, road_class="residential",
                                             name=f"Column {i}", attrs=dict(attrs or {}))))
    with session_scope() as session:
        return write_network(session, name, lines)


def token(role: str, name: str | None = None) -> str:
    """A new API token of ``role``."""
    with session_scope() as session:
        return create_token(session, name or f"{role}-{uuid.uuid4().hex[:6]}", role)


def bearer(role: str) -> dict[str, str]:
    """The Authorization header of a new token of ``role``."""
    return {"Authorization": f"Bearer {token(role)}"}


class NoteWatch:
    """What this process's network-change listener has passed on about one network: the
    newest version it has told every subscriber that joined before this watch (the MVT cache,
    the routing graphs; subscribers are told in the order they joined), so a test knows a
    write's invalidation has landed instead of racing it."""

    def __init__(self, database_url: str, network_id: int) -> None:
        self.network_id = network_id
        self.version = 0
        self._changed = threading.Condition()
        network_changes(database_url, Subscriber(self._on_note, lambda: None, lambda: None))

    def _on_note(self, note: dict) -> None:
        if int(note["network_id"]) == self.network_id:
            with self._changed:
                self.version = max(self.version, int(note["version"]))
                self._changed.notify_all()

    def wait_for(self, version: int, timeout_s: float = 10.0) -> bool:
        """Whether the note of ``version`` (or a later one) was passed on within the time."""
        with self._changed:
            return self._changed.wait_for(lambda: self.version >= version, timeout_s)


def node_pairs(conn: psycopg.Connection, net: int, n: int, edges: str,
               seed: int = 42) -> list[tuple[tuple[int, float, float], ...]]:
    """``n`` random pairs of (id, lon, lat) of nodes inside the largest strongly connected
    component of the pgRouting ``edges`` query: pairs that have a route."""
    rows = conn.execute(
        "WITH c AS (SELECT component, node FROM pgr_strongComponents(%s)), "
        "big AS (SELECT component FROM c GROUP BY component ORDER BY count(*) DESC LIMIT 1) "
        "SELECT n.id, ST_X(n.geom), ST_Y(n.geom) FROM c JOIN big USING (component) "
        "JOIN road_nodes n ON n.id = c.node ORDER BY n.id", (edges,)).fetchall()
    rng = random.Random(seed)
    return [tuple(rng.sample(rows, 2)) for _ in range(n)]
