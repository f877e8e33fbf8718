"""In-process MVT cache, kept fresh by PostgreSQL NOTIFY in every server worker.

Every committed change to a network's segments or nodes NOTIFYs ``network_changed`` with the
new network version and the changed bbox (migration 0002). The worker's network-change
listener (:mod:`app.db.notify`) drops the cached tiles meeting that bbox.

Read-your-writes without waiting for the listener: a request passes the network version it
read from the database; if that is newer than the last version the listener has applied, a
notification is still in flight, so the cache is bypassed (and nothing is stored) until it
lands. A tile rendered from an older version is never stored after a newer change was seen.
While the listener is disconnected the cache is bypassed, and cleared on reconnect, since
notifications sent meanwhile are lost.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

from app.db.notify import Subscriber, network_changes

Bounds = tuple[float, float, float, float]
TileKey = tuple[int, int, int, int]  # network id, z, x, y


def _intersects(a: Bounds, b: Bounds) -> bool:
    return a[0] <= b[2] and b[0] <= a[2] and a[1] <= b[3] and b[1] <= a[3]


class TileCache:
    """Per-worker LRU of vector tiles, keyed by network and tile and valid for one network version;
    bounds let a change drop only the tiles it meets."""
    def __init__(self, max_tiles: int = 4096) -> None:
        self._lock = threading.Lock()
        self._tiles: OrderedDict[TileKey, tuple[Bounds, bytes]] = OrderedDict()
        self._known: dict[int, int] = {}
        self.max_tiles = max_tiles
        self.healthy = False

    def get(self, key: TileKey, version: int) -> bytes | None:
        """The cached tile, if it was made at ``version`` and the change feed is up (otherwise a
        tile could be stale)."""
        with self._lock:
            if not self.healthy or self._known.setdefault(key[0], version) != version:
                return None
            entry = self._tiles.get(key)
            if entry is None:
                return None
            self._tiles.move_to_end(key)
            return entry[1]

    def put(self, key: TileKey, version: int, bounds: Bounds, tile: bytes) -> None:
        """Keep a tile made at ``version`` unless the network has moved on meanwhile."""
        with self._lock:
            if not self.healthy or self._known.get(key[0]) != version:
                return
            self._tiles[key] = (bounds, tile)
            while len(self._tiles) > self.max_tiles:
                self._tiles.popitem(last=False)

    def invalidate(self, network_id: int, version: int, bbox: Bounds | None) -> int:
        """Apply one notification; returns how many tiles were dropped."""
        with self._lock:
            self._known[network_id] = max(self._known.get(network_id, version), version)
            stale = [k for k, (bounds, _) in self._tiles.items() if k[0] == network_id
                     and (bbox is None or _intersects(bounds, bbox))]
            for k in stale:
                del self._tiles[k]
            return len(stale)

    def reset(self, healthy: bool) -> None:
        """Forget everything (the change feed dropped or came back: notes may have been missed)."""
        with self._lock:
            self._tiles.clear()
            self._known.clear()
            self.healthy = healthy



def _invalidate(note: dict) -> None:
    bbox = tuple(note["bbox"]) if note.get("bbox") else None  # None (e.g. deleted): every tile
    _cache.invalidate(int(note["network_id"]), int(note["version"]), bbox)


_cache = TileCache()
_subscribed: set[str] = set()
_subscribe_lock = threading.Lock()


def shared_cache(database_url: str) -> TileCache:
    """This process's cache, subscribed to the process's network-change listener once."""
    with _subscribe_lock:
        if database_url not in _subscribed:
            _subscribed.add(database_url)
            network_changes(database_url, Subscriber(
                on_note=_invalidate,
                on_connect=lambda: _cache.reset(healthy=True),
                on_disconnect=lambda: _cache.reset(healthy=False)))
    return _cache
