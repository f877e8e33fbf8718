"""References into the raster store, kept relative to ``UGVMAP_RASTER_STORE`` in the catalogue.

Why relative: a backup restored on another machine, or into another store directory, must find
its COGs there. The catalogue (``raster_sources.uri``, ``layers.overview_uri``) holds
``<layer>/<uuid>.tif``; :func:`resolve` joins it to the configured store when a file is read.
A reference that is already absolute (a path or a GDAL URI such as ``/vsis3/...`` or
``s3://...``, registered outside the store) is used as it is.

Resolving is a string join on every tile: the store root is computed once per settings value
(``Path.resolve`` is a filesystem call, not free on the tile path).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from functools import lru_cache
from pathlib import Path

from sqlalchemy import Engine, text

from app.settings import get_settings


@lru_cache(maxsize=8)
def _root(raster_store: str | None, data_dir: str) -> str:
    return (raster_store or str((Path(data_dir) / "rasters").resolve())).rstrip("/")


def store_root() -> str:
    """The configured raster store (a directory, or a GDAL-readable prefix), no trailing '/'."""
    settings = get_settings()
    return _root(settings.raster_store, str(settings.data_dir))


def is_absolute(uri: str) -> bool:
    """A path from the filesystem root or a URI with a scheme: not relative to the store."""
    return uri.startswith("/") or "://" in uri


def resolve(uri: str) -> str:
    """Where to read a catalogue reference: store-relative ones are joined to the store."""
    return uri if is_absolute(uri) else f"{store_root()}/{uri}"


def relative(path: str | Path) -> str:
    """The catalogue reference for a file written into the store: its path below the store
    (unchanged when it lies elsewhere)."""
    text, root = str(path), store_root()
    return text[len(root) + 1:] if text.startswith(root + "/") else text


# -- deleting files vs. backups ----------------------------------------------------------------
STORE_LOCK = "ugvmap.raster-store"
"""Advisory lock between whoever deletes store files (shared) and a backup (exclusive).

A file is deleted only after the commit that drops its reference; a backup copies the files
its database snapshot references. Holding this lock exclusively from before the snapshot until
the last file is copied makes a deletion committed meanwhile wait to remove its file, so every
file the snapshot names is still there to copy."""


@contextmanager
def deleting_files(engine: Engine) -> Iterator[None]:
    """Hold the store lock shared while unlinking files (waits while a backup copies)."""
    with engine.connect() as conn:
        conn.execute(text("SELECT pg_advisory_lock_shared(hashtext(:k))"), {"k": STORE_LOCK})
        conn.commit()
        try:
            yield
        finally:
            conn.execute(text("SELECT pg_advisory_unlock_shared(hashtext(:k))"),
                         {"k": STORE_LOCK})
            conn.commit()


def remove_files(engine: Engine, uris: Iterable[str]) -> None:
    """Unlink store files whose references were just deleted (missing ones are fine)."""
    with deleting_files(engine):
        for uri in uris:
            Path(resolve(uri)).unlink(missing_ok=True)
