"""One LISTEN connection per worker process for ``network_changed``, shared by its users.

The MVT tile cache and the routing graphs both follow the notifications that migration
``0002_network_change_notify`` sends when a network edit commits. One listener per process and
database (instead of one per user) halves the idle connections, and keeps the reconnect loop,
the payload parsing and the guard against a malformed payload in one place.

A subscriber gives three callbacks: ``on_note(payload)`` with the parsed JSON object,
``on_connect()`` after every (re)connect once LISTEN is in place (notifications may have been
missed before it), and ``on_disconnect()`` when the connection is lost. A callback that raises
is logged and does not stop the listener or the other subscribers.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import psycopg

from app.db.session import libpq_dsn

log = logging.getLogger(__name__)

CHANNEL = "network_changed"
IDLE_CHECK_S = 10.0


@dataclass(frozen=True)
class Subscriber:
    """What a listener tells its subscribers: each change note, and when the connection comes back
    or drops (caches must assume they missed notes while it was down)."""
    on_note: Callable[[dict], None]
    on_connect: Callable[[], None]
    on_disconnect: Callable[[], None]


class NetworkChangeListener(threading.Thread):
    """LISTEN on ``network_changed`` forever, reconnecting with backoff after errors."""

    def __init__(self, database_url: str) -> None:
        super().__init__(name="network-changed-listener", daemon=True)
        self.dsn = libpq_dsn(database_url)
        self.ready = threading.Event()
        """Set once LISTEN has been in place (or the first attempt failed): waiters go on."""
        self._subscribers: list[Subscriber] = []
        self._lock = threading.Lock()
        self._connected = False

    def subscribe(self, subscriber: Subscriber) -> None:
        """Add a subscriber; one that joins while connected is told at once, as if it had seen the
        connect."""
        with self._lock:
            self._subscribers.append(subscriber)
            connected = self._connected
        if connected:  # joined late: it missed nothing it could have known about
            self._call(subscriber.on_connect)

    def _each(self, pick: Callable[[Subscriber], Callable[..., None]], *args: object) -> None:
        with self._lock:
            subscribers = list(self._subscribers)
        for subscriber in subscribers:
            self._call(pick(subscriber), *args)

    @staticmethod
    def _call(callback: Callable[..., None], *args: object) -> None:
        try:
            callback(*args)
        except Exception:  # one subscriber's bug must not silence the others
            log.exception("%s subscriber failed", CHANNEL)

    def run(self) -> None:
        """LISTEN until the process ends, reconnecting with backoff; subscribers hear every note and
        every connection change."""
        backoff = 0.5
        while True:
            try:
                with psycopg.connect(self.dsn, autocommit=True, connect_timeout=5) as conn:
                    conn.execute(f"LISTEN {CHANNEL}")
                    with self._lock:
                        self._connected = True
                    self._each(lambda s: s.on_connect)
                    self.ready.set()
                    backoff = 0.5
                    while True:
                        for note in conn.notifies(timeout=IDLE_CHECK_S):
                            self._dispatch(note.payload)
                        conn.execute("SELECT 1")  # notice a dead connection while idle
            except Exception as exc:  # keep the worker serving; users fall back meanwhile
                with self._lock:
                    was_connected, self._connected = self._connected, False
                self._each(lambda s: s.on_disconnect)
                self.ready.set()
                (log.warning if was_connected or backoff == 0.5 else log.debug)(
                    "%s listener disconnected (%s); retrying", CHANNEL, exc)
                time.sleep(backoff)
                backoff = min(backoff * 2, 10.0)

    def _dispatch(self, payload: str) -> None:
        try:
            note = json.loads(payload)
            int(note["network_id"]), int(note["version"])
        except (ValueError, KeyError, TypeError):
            log.warning("ignoring malformed %s payload %r", CHANNEL, payload[:200])
            return
        self._each(lambda s: s.on_note, note)


_listeners: dict[str, NetworkChangeListener] = {}
_start_lock = threading.Lock()


def network_changes(database_url: str, subscriber: Subscriber,
                    wait_s: float = 2.0) -> NetworkChangeListener:
    """Subscribe to this process's listener for ``database_url`` (started on first use) and
    wait up to ``wait_s`` for LISTEN to be in place."""
    with _start_lock:
        listener = _listeners.get(database_url)
        if listener is None:
            listener = _listeners[database_url] = NetworkChangeListener(database_url)
            listener.start()
    listener.subscribe(subscriber)
    listener.ready.wait(timeout=wait_s)
    return listener
