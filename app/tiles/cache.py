"""In-process LRU of encoded tiles, bounded in bytes.

Keys carry the layer id and version, so an ingest (which bumps the version) makes every old
entry unreachable at once: no explicit invalidation, stale entries just age out. Each worker
process has its own cache; ``UGVMAP_TILE_CACHE_MB=0`` turns it off (the benchmark does, to
measure rendering).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Hashable
from functools import lru_cache

from app.settings import get_settings


class TileCache:
    """Per-worker LRU of encoded raster tiles, bounded in bytes; keys carry the layer version, so a
    re-ingest never serves an old tile."""
    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._items: OrderedDict[Hashable, bytes] = OrderedDict()
        self._size = 0
        self._lock = threading.Lock()

    def get(self, key: Hashable) -> bytes | None:
        """The cached tile body, marked as recently used."""
        with self._lock:
            body = self._items.get(key)
            if body is not None:
                self._items.move_to_end(key)
            return body

    def put(self, key: Hashable, body: bytes) -> None:
        """Keep a tile body, evicting the least recently used beyond the budget."""
        if len(body) > self.max_bytes:
            return
        with self._lock:
            if key in self._items:
                return
            self._items[key] = body
            self._size += len(body)
            while self._size > self.max_bytes:
                _, old = self._items.popitem(last=False)
                self._size -= len(old)


@lru_cache(maxsize=1)
def tile_cache() -> TileCache:
    """The worker's one tile cache, sized by ``UGVMAP_TILE_CACHE_MB``."""
    return TileCache(get_settings().tile_cache_mb * 1024 * 1024)
