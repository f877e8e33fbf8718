"""The raster store (``UGVMAP_RASTER_STORE``): where source and overview COGs live.

A local directory (the default) or an S3 prefix, ``s3://bucket/prefix``. Both have one
interface, used by ingest (write, sweep, delete), tiles (read) and backups:

- ``ref(key)``: what the catalogue records for the object ``key`` (``layer/<uuid>.tif``): in
  the configured store the key itself, so a backup restored on another machine or into
  another store finds its COGs there (migration ``0007_store_uris`` made older absolute paths
  relative);
- ``resolve(ref)``: the GDAL path to open for a catalogue value: the store root joined to a
  relative key, or an absolute path / ``s3://`` URI as it is (rows registered outside the
  store). Resolving is a string join on every tile, never a filesystem call;
- ``put(local, key)``: make a finished local file the object ``key``, atomically: a local
  rename, or an S3 upload (multipart above 8 MB) that only exists once complete;
- ``delete(refs)``, ``refs_under(layer)`` (what a sweep compares with the catalogue) and
  ``staging(layer)`` (where COGs are written before ``put``).

S3: uploads and deletes go through boto3 (its transfer manager does the multipart upload with
retries and aborts it on failure, so a failed upload leaves no part behind); reads go through
GDAL's ``/vsis3/`` (COG range reads are GDAL's job). Both take credentials and endpoint from
the usual AWS_* variables; ``AWS_ENDPOINT_URL`` (boto3's) and ``AWS_S3_ENDPOINT`` +
``AWS_HTTPS`` (GDAL's) are each derived from the other, and ``AWS_VIRTUAL_HOSTING=FALSE``
gives path-style addressing to both (MinIO, moto, Ceph).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from abc import ABC, abstractmethod
from collections.abc import Iterable, Iterator
from functools import lru_cache
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from sqlalchemy import Connection, Engine, text

from app.errors import UserError
from app.settings import default_data_dir, get_settings

#: Set around each /vsis3/ open (thread-local, via ``rasterio.Env``), not process-wide: they
#: would change how *local* inputs open (no sidecar files, no world files).
REMOTE_OPEN_OPTIONS = {
    # Our COGs have no sidecars: don't LIST the "directory" on every open.
    "GDAL_DISABLE_READDIR_ON_OPEN": "EMPTY_DIR",
    "CPL_VSIL_CURL_ALLOWED_EXTENSIONS": ".tif",
    # One GET brings the COG header and every IFD (a few kB; ours fit in 32 kB).
    "GDAL_INGESTED_BYTES_AT_OPEN": "32768",
    # Per open handle (handles stay open, readers.MAX_OPEN_PER_THREAD of them per thread).
    "VSI_CACHE": "TRUE",
    "VSI_CACHE_SIZE": str(2 << 20),
}
#: HTTP-only options, set process-wide (unless already set) once a remote store is opened.
#: Objects are immutable (every write is a new name), so GDAL's per-process caches of file
#: sizes/existence (HEAD results) and of downloaded blocks can never serve stale bytes.
HTTP_OPTIONS = {
    # HTTP/2 (GDAL's default over TLS) multiplexed; plain http stays keep-alive HTTP/1.1.
    "GDAL_HTTP_MULTIPLEX": "YES",
    "GDAL_HTTP_MERGE_CONSECUTIVE_RANGES": "YES",
    "CPL_VSIL_CURL_CACHE_SIZE": str(128 << 20),  # shared block cache (default 16 MB)
    "CPL_VSIL_CURL_USE_HEAD": "NO",  # the first ranged GET tells the size: one round trip
    "GDAL_HTTP_MAX_RETRY": "3",
    "GDAL_HTTP_RETRY_DELAY": "0.5",
}
MULTIPART_THRESHOLD = 8 << 20
MULTIPART_CHUNK = 16 << 20


class StoreError(UserError):
    """The raster store is misconfigured or unreachable; the message says how."""


class RasterStore(ABC):
    """Where COGs live; see the module docstring for the contract."""

    root: str
    remote: bool = False

    def ref(self, key: str) -> str:
        """What the catalogue records for object ``key``: the key itself in the configured
        store (so the catalogue moves with a backup to any store), the full location in any
        other (e.g. a test's or benchmark's own store), which would otherwise be lost."""
        return key if self.root == open_store().root else self.location(key)

    @abstractmethod
    def location(self, key: str) -> str:
        """The object's absolute path or URI."""

    @abstractmethod
    def resolve(self, ref: str) -> str:
        """The GDAL path of a catalogue value (relative key, absolute path or URI)."""

    @abstractmethod
    def put(self, local: Path, key: str) -> None:
        """Make the finished file ``local`` the object ``key`` (it is consumed)."""

    def presign(self, ref: str, expires_s: int = 3600) -> str | None:
        """A time-limited URL a client can download ``ref`` from directly, if the store has
        one (S3), else None (the app serves the file)."""
        return None

    @abstractmethod
    def delete(self, refs: Iterable[str]) -> None:
        """Remove these objects; missing ones are fine."""

    @abstractmethod
    def refs_under(self, layer: str) -> list[str]:
        """Every object under ``layer/``, as catalogue values, temporary files included."""

    @abstractmethod
    def staging(self, layer: str) -> contextlib.AbstractContextManager[Path]:
        """A local directory to write ``layer``'s COGs in before :meth:`put`."""


def is_absolute(ref: str) -> bool:
    """A path from the filesystem root or a URI with a scheme: not relative to the store."""
    return ref.startswith("/") or "://" in ref


class LocalStore(RasterStore):
    """A directory; COGs are written in place and renamed when complete."""

    def __init__(self, root: Path) -> None:
        self.path = root.resolve()
        self.root = str(self.path)

    def location(self, key: str) -> str:
        """The file's absolute path."""
        return f"{self.root}/{key}"

    def resolve(self, ref: str) -> str:
        """Absolute paths and URIs as they are (``s3://`` as GDAL's /vsis3/); keys under root."""
        if ref.startswith("s3://"):
            return "/vsis3/" + ref.removeprefix("s3://")
        return ref if is_absolute(ref) else f"{self.root}/{ref}"

    def put(self, local: Path, key: str) -> None:
        """Rename into place (a no-op when written there already)."""
        dst = self.path / key
        if local.resolve() != dst:
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.replace(local, dst)

    def delete(self, refs: Iterable[str]) -> None:
        """Unlink each file."""
        for ref in refs:
            Path(self.resolve(ref)).unlink(missing_ok=True)

    def refs_under(self, layer: str) -> list[str]:
        """The files in the layer's folder, as keys."""
        folder = self.path / layer
        return [f"{layer}/{p.name}" for p in folder.iterdir() if p.is_file()] \
            if folder.is_dir() else []

    @contextlib.contextmanager
    def staging(self, layer: str) -> Iterator[Path]:
        """The layer's own folder: files are written under temporary names, then renamed."""
        folder = self.path / layer
        folder.mkdir(parents=True, exist_ok=True)
        yield folder


class S3Store(RasterStore):
    """An S3 bucket and prefix: COGs are written locally, then uploaded."""

    remote = True

    def __init__(self, uri: str) -> None:
        parts = urlsplit(uri)
        if not parts.netloc:
            raise StoreError(f"UGVMAP_RASTER_STORE={uri!r}: expected s3://bucket[/prefix]")
        self.bucket = parts.netloc
        prefix = parts.path.strip("/")
        self.prefix = f"{prefix}/" if prefix else ""
        self.root = f"s3://{self.bucket}/{self.prefix}"
        configure_gdal_http()
        self.client = s3_client()

    def key_of(self, ref: str) -> str | None:
        """The object key of a catalogue value in this bucket, or None for anything else."""
        if ref.startswith("s3://"):
            bucket, _, key = ref.removeprefix("s3://").partition("/")
            return key if bucket == self.bucket else None
        return None if is_absolute(ref) else self.prefix + ref

    def location(self, key: str) -> str:
        """The object's ``s3://`` URI."""
        return f"{self.root}{key}"

    def resolve(self, ref: str) -> str:
        """``/vsis3/bucket/key`` for a URI or a key; local paths as they are."""
        if ref.startswith("s3://"):
            return "/vsis3/" + ref.removeprefix("s3://")
        return ref if is_absolute(ref) else f"/vsis3/{self.bucket}/{self.prefix}{ref}"

    @contextlib.contextmanager
    def _errors(self, doing: str) -> Iterator[None]:
        """S3 failures (no bucket, no credentials, endpoint down) as one clear line."""
        from boto3.exceptions import Boto3Error
        from botocore.exceptions import BotoCoreError, ClientError

        try:
            yield
        except (ClientError, BotoCoreError, Boto3Error) as exc:
            raise StoreError(f"raster store {self.root}: {doing} failed ({exc})") from exc

    def put(self, local: Path, key: str) -> None:
        """Upload (multipart above 8 MB; an incomplete upload is aborted, never visible)."""
        from boto3.s3.transfer import TransferConfig

        config = TransferConfig(multipart_threshold=MULTIPART_THRESHOLD,
                                multipart_chunksize=MULTIPART_CHUNK)
        try:
            with self._errors(f"uploading {key}"):
                self.client.upload_file(str(local), self.bucket, self.prefix + key,
                                        Config=config)
        finally:
            local.unlink(missing_ok=True)

    def presign(self, ref: str, expires_s: int = 3600) -> str | None:
        """A presigned GET URL (ranges work on it, so GDAL's /vsicurl/ reads it in place)."""
        key = self.key_of(ref)
        if key is None:
            return None
        with self._errors("presigning"):
            url: str = self.client.generate_presigned_url(
                "get_object", Params={"Bucket": self.bucket, "Key": key}, ExpiresIn=expires_s)
        return url

    def delete(self, refs: Iterable[str]) -> None:
        """Batch-delete the objects of this bucket among ``refs``."""
        keys = [k for k in (self.key_of(r) for r in refs) if k]
        with self._errors("deleting"):
            for i in range(0, len(keys), 1000):
                self.client.delete_objects(Bucket=self.bucket, Delete={
                    "Objects": [{"Key": k} for k in keys[i:i + 1000]], "Quiet": True})

    def refs_under(self, layer: str) -> list[str]:
        """Every object directly under ``prefix/layer/``, as keys (as the local store lists
        the files of the layer's folder, not of its subfolders)."""
        with self._errors("listing"):
            pages = self.client.get_paginator("list_objects_v2").paginate(
                Bucket=self.bucket, Prefix=f"{self.prefix}{layer}/", Delimiter="/")
            return [o["Key"].removeprefix(self.prefix) for page in pages
                    for o in page.get("Contents", [])]

    @contextlib.contextmanager
    def staging(self, layer: str) -> Iterator[Path]:
        """A temporary local directory (``TMPDIR``), removed afterwards."""
        folder = Path(tempfile.mkdtemp(prefix=f"ugvmap-{layer}-"))
        try:
            yield folder
        finally:
            shutil.rmtree(folder, ignore_errors=True)


def _truthy(name: str, default: bool) -> bool:
    value = os.environ.get(name)
    return default if value is None else value.strip().upper() not in ("NO", "FALSE", "0", "OFF")


def configure_gdal_http() -> None:
    """Process-wide GDAL settings for a remote store (only those the user has not set).

    ``AWS_ENDPOINT_URL`` (what boto3 and the AWS CLI read) becomes GDAL's
    ``AWS_S3_ENDPOINT`` + ``AWS_HTTPS``, so one variable configures both.
    """
    for key, value in HTTP_OPTIONS.items():
        os.environ.setdefault(key, value)
    endpoint = os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get("AWS_ENDPOINT_URL")
    if endpoint and "AWS_S3_ENDPOINT" not in os.environ:
        parts = urlsplit(endpoint)
        os.environ["AWS_S3_ENDPOINT"] = parts.netloc + parts.path.rstrip("/")
        os.environ.setdefault("AWS_HTTPS", "NO" if parts.scheme == "http" else "YES")


def s3_client() -> Any:
    """A boto3 S3 client on the endpoint, region and addressing style of the AWS_* variables."""
    import boto3
    from botocore.config import Config

    endpoint = os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get("AWS_ENDPOINT_URL")
    if not endpoint and os.environ.get("AWS_S3_ENDPOINT"):
        scheme = "https" if _truthy("AWS_HTTPS", True) else "http"
        endpoint = f"{scheme}://{os.environ['AWS_S3_ENDPOINT']}"
    style = "auto" if _truthy("AWS_VIRTUAL_HOSTING", True) else "path"
    region = os.environ.get("AWS_REGION") or os.environ.get("AWS_DEFAULT_REGION")
    return boto3.client("s3", endpoint_url=endpoint, region_name=region,
                        config=Config(s3={"addressing_style": style},
                                      retries={"max_attempts": 5, "mode": "standard"}))


@lru_cache(maxsize=4)
def _open(root: str) -> RasterStore:
    if root.startswith("s3://"):
        return S3Store(root)
    if "://" in root or root.startswith("/vsi"):
        raise StoreError(f"UGVMAP_RASTER_STORE={root!r}: a directory or s3://bucket/prefix")
    return LocalStore(Path(root))


def open_store(root: str | Path | RasterStore | None = None) -> RasterStore:
    """The store at ``root`` (default: ``UGVMAP_RASTER_STORE``), one instance per root."""
    if isinstance(root, RasterStore):
        return root
    return _open(str(root) if root is not None else get_settings().raster_store_uri)


def store_root() -> str:
    """The configured store's root: a directory path, or ``s3://bucket/prefix/``."""
    return open_store().root


def resolve(ref: str) -> str:
    """Where to read a catalogue reference, in the configured store."""
    return open_store().resolve(ref)


# -- deleting files vs. backups ----------------------------------------------------------------
STORE_LOCK = "ugvmap.raster-store"
"""Advisory lock between whoever deletes store files (shared) and a backup (exclusive).

A file is deleted only after the commit that drops its reference; a backup copies the files
its database snapshot references. Holding this lock exclusively from before the snapshot until
the last file is copied makes a deletion committed meanwhile wait to remove its file, so every
file the snapshot names is still there to copy."""


@contextlib.contextmanager
def deleting_files(engine: Engine) -> Iterator[None]:
    """Hold the store lock shared while deleting files (waits while a backup copies)."""
    with engine.connect() as conn:
        conn.execute(text("SELECT pg_advisory_lock_shared(hashtext(:k))"), {"k": STORE_LOCK})
        conn.commit()
        try:
            yield
        finally:
            conn.execute(text("SELECT pg_advisory_unlock_shared(hashtext(:k))"),
                         {"k": STORE_LOCK})
            conn.commit()


def remove_files(engine: Engine, refs: Iterable[str],
                 store: RasterStore | None = None) -> None:
    """Delete store objects whose references were just deleted (missing ones are fine)."""
    with deleting_files(engine):
        (store or open_store()).delete(refs)


# -- the store a database's files live in ------------------------------------------------------
RECORD_ROOT = ("INSERT INTO raster_store (root) VALUES (:root) ON CONFLICT (id) DO UPDATE "
               "SET root = EXCLUDED.root, recorded_at = now()")


def recorded_root(conn: Connection) -> str | None:
    """The raster store this database's relative references are keys of (None: no ingest
    has recorded one yet)."""
    root: str | None = conn.execute(text("SELECT root FROM raster_store")).scalar()
    return root


def mismatch(recorded: str, configured: str) -> str:
    """Why a process configured with store ``configured`` must not use this database's files,
    and how to fix it."""
    return (f"this database's rasters are in {recorded}, but this process's raster store is "
            f"{configured} (UGVMAP_RASTER_STORE, else UGVMAP_DATA_DIR/rasters, else "
            f"{default_data_dir()}/rasters). Run it with UGVMAP_RASTER_STORE={recorded}, or, if "
            f"the files were moved, `ugvmap db store --set NEW_ROOT`")


def claim_root(conn: Connection) -> None:
    """Before an ingest writes into the configured store: record it as the database's store
    (the first ingest), or refuse with :func:`mismatch` when the database's files are
    elsewhere, so no layer gets registered whose files no server finds."""
    root = store_root()
    recorded = recorded_root(conn)
    if recorded is None:
        conn.execute(text("INSERT INTO raster_store (root) VALUES (:root) "
                          "ON CONFLICT (id) DO NOTHING"), {"root": root})
        recorded = recorded_root(conn)
    if recorded != root:
        raise StoreError(mismatch(recorded or "", root))
