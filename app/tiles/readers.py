"""Open-dataset cache for tile rendering.

Opening a COG costs a few hundred microseconds (header + IFD parsing), a large share of a
tile that is otherwise one block read, so handles stay open. GDAL dataset handles must not be
shared between threads, hence one small LRU per worker thread. Catalogue values are resolved
against the raster store here (:mod:`app.tiles.store`); remote ones open with the store's
remote-open GDAL options.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from functools import lru_cache

import rasterio
from rasterio.errors import RasterioIOError
from rasterio.io import DatasetReader

from app.tiles.store import REMOTE_OPEN_OPTIONS, configure_gdal_http, open_store

MAX_OPEN_PER_THREAD = 64
_local = threading.local()


def open_dataset(uri: str) -> DatasetReader:
    """A cached, open dataset for the catalogue value ``uri`` (owned by the calling thread)."""
    cache: OrderedDict[str, DatasetReader] | None = getattr(_local, "cache", None)
    if cache is None:
        cache = _local.cache = OrderedDict()
    ds = cache.get(uri)
    if ds is not None:
        cache.move_to_end(uri)
        return ds
    ds = open_raster(open_store().resolve(uri))
    cache[uri] = ds
    if len(cache) > MAX_OPEN_PER_THREAD:
        _, oldest = cache.popitem(last=False)
        oldest.close()
    return ds


def open_raster(path: str) -> DatasetReader:
    """``rasterio.open``, with the remote-open options for object-store paths (and the HTTP
    ones, even when the configured store is local but the catalogue names S3 objects)."""
    if not path.startswith("/vsi"):
        return rasterio.open(path)
    configure_gdal_http()
    with rasterio.Env(**REMOTE_OPEN_OPTIONS):
        return rasterio.open(path)


@lru_cache(maxsize=1024)
def overview_zoom(uri: str) -> int:
    """The XYZ zoom a layer overview COG was written at (files are immutable: cache it)."""
    try:
        return int(open_dataset(uri).tags(ns="TILING_SCHEME").get("ZOOM_LEVEL", -1))
    except RasterioIOError:
        return -1
