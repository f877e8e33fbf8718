"""``ugvmap backup DIR`` / ``ugvmap restore DIR``: the database and the raster store, together.

A backup directory holds ``database.dump`` (``pg_dump`` custom format, made by the newest
installed PostgreSQL client: the embedded cluster's own PostgreSQL 15 binaries here),
``rasters/`` (every COG the dump references, at its store-relative path) and
``manifest.json`` (written last: sizes and SHA-256 of every file, the schema revision, row
counts). A directory without a manifest is not a backup.

Consistency: the dump and the file list come from one database snapshot. The backup opens a
REPEATABLE READ transaction, exports its snapshot and runs ``pg_dump --snapshot`` on it, and
lists the referenced files in that same transaction. Files are immutable (every ingest writes
new names) and deleted only after the commit that drops their reference; deleters hold the
store lock shared while unlinking (:mod:`app.tiles.store`) and the backup holds it exclusively
from before the snapshot until the last file is copied, so every file the snapshot names is
still there. Ingests and edits go on meanwhile; they are simply not in this backup.

Restore goes into an EMPTY database (no ugvmap tables) and a store directory that does not
already hold different files of the same name. Everything is verified against the manifest
first; files are copied before the catalogue rows exist (as an ingest does), the dump is
restored in one transaction (all or nothing), and the schema is then migrated to the code's
head. Store references are relative (migration ``0007_store_uris``), so the restored catalogue
reads the new store wherever it is.
"""

from __future__ import annotations

import glob
import hashlib
import json
import shutil
import subprocess
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import psycopg

from app.db import migrate
from app.db.session import libpq_dsn
from app.errors import UserError
from app.tiles.store import STORE_LOCK, is_absolute

MANIFEST = "manifest.json"
DUMP = "database.dump"
RASTERS = "rasters"
FORMAT = 1
COUNTED = ("layers", "raster_sources", "networks", "road_segments", "road_nodes",
           "segment_edits", "node_edits", "api_tokens", "layer_labels", "change_sets",
           "proposed_changes", "segment_lanes", "lane_boundaries", "lane_boundary_edits")
"""Tables whose rows the manifest counts and a restore checks: everything a person made or
edited (the dump holds every table; these are what a silent loss would cost)."""
CHUNK = 1 << 20

Progress = Callable[[str, int], None]
"""``progress(step, bytes_done)``: told as each file is copied or verified."""


class BackupError(UserError):
    """A backup or restore that cannot go on; the message says why and changes nothing."""


@dataclass(frozen=True)
class Summary:
    """What a backup or restore covered, for the command's one-line report."""

    directory: Path
    revision: str
    files: int
    bytes: int
    counts: dict[str, int]
    external: int = 0


def _tool(name: str) -> str:
    """The newest installed PostgreSQL client binary ``name`` (Debian keeps them off PATH in
    /usr/lib/postgresql/<major>/bin): pg_dump must be at least the server's version, and
    pg_restore at least the version of the pg_dump that wrote the dump."""
    found = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"),
                   key=lambda p: int(Path(p).parts[-3]) if Path(p).parts[-3].isdigit() else 0)
    path = found[-1] if found else shutil.which(name)
    if path is None:
        raise BackupError(f"{name} not found; install the PostgreSQL client of the server's "
                          "version (postgresql-client-15 for the embedded cluster)")
    return path


def _run(cmd: list[str]) -> None:
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        detail = lines[-1] if lines else f"exit status {proc.returncode}"
        raise BackupError(f"{Path(cmd[0]).name} failed: {detail}")


def sha256_copy(src: Path, dst: Path | None = None) -> tuple[str, int]:
    """SHA-256 and size of ``src``, copied to ``dst`` on the way when given (one read)."""
    digest, size = hashlib.sha256(), 0
    with open(src, "rb") as fin:
        out = open(dst, "wb") if dst else None  # noqa: SIM115 - closed below
        try:
            while block := fin.read(CHUNK):
                digest.update(block)
                size += len(block)
                if out:
                    out.write(block)
        finally:
            if out:
                out.close()
    return digest.hexdigest(), size


def _one(conn: psycopg.Connection, sql: str) -> Any:
    row = conn.execute(sql).fetchone()
    assert row is not None  # aggregates and functions always return a row
    return row[0]


def _counts(conn: psycopg.Connection) -> dict[str, int]:
    return {t: _one(conn, f"SELECT count(*) FROM {t}") for t in COUNTED}


def backup(dest: Path, database_url: str, store_root: str,
           progress: Progress | None = None) -> Summary:
    """Write a consistent backup of the database and the raster store into ``dest``."""
    report = progress or (lambda step, done: None)
    if dest.exists() and any(dest.iterdir()):
        raise BackupError(f"{dest} is not empty; back up into a new directory")
    if is_absolute(store_root) and "://" in store_root:
        raise BackupError(f"the raster store {store_root} is not a local directory")
    dest.mkdir(parents=True, exist_ok=True)
    dsn = libpq_dsn(database_url)
    with psycopg.connect(dsn, autocommit=True) as lock, psycopg.connect(dsn) as conn:
        lock.execute("SELECT pg_advisory_lock(hashtext(%s))", (STORE_LOCK,))
        conn.execute("SET TRANSACTION ISOLATION LEVEL REPEATABLE READ, READ ONLY")
        snapshot = _one(conn, "SELECT pg_export_snapshot()")
        revision = _one(conn, "SELECT version_num FROM alembic_version")
        uris = [r[0] for r in conn.execute(
            "SELECT uri FROM raster_sources UNION SELECT overview_uri FROM layers "
            "WHERE overview_uri IS NOT NULL ORDER BY 1")]
        counts = _counts(conn)
        report("dumping the database", 0)
        _run([_tool("pg_dump"), "--format=custom", f"--snapshot={snapshot}",
              f"--file={dest / DUMP}", f"--dbname={dsn}"])
        files, external, total = [], [u for u in uris if is_absolute(u)], 0
        for uri in (u for u in uris if not is_absolute(u)):
            src, dst = Path(store_root) / uri, dest / RASTERS / uri
            if not src.is_file():
                raise BackupError(f"{src} is referenced by the catalogue but missing; "
                                  "the backup would not restore it")
            dst.parent.mkdir(parents=True, exist_ok=True)
            digest, size = sha256_copy(src, dst)
            files.append({"path": uri, "bytes": size, "sha256": digest})
            total += size
            report(uri, total)
        conn.rollback()
    digest, size = sha256_copy(dest / DUMP)
    manifest = {"format": FORMAT, "created_at": datetime.now(UTC).isoformat(),
                "database": {"file": DUMP, "bytes": size, "sha256": digest,
                             "revision": revision, "counts": counts},
                "store": {"source_root": store_root, "files": files, "external": external}}
    (dest / MANIFEST).write_text(json.dumps(manifest, indent=1))
    return Summary(dest, revision, len(files), total + size, counts, len(external))


def read_manifest(src: Path) -> dict[str, Any]:
    """The backup's manifest, or a clear error when ``src`` is not a complete backup."""
    try:
        manifest = json.loads((src / MANIFEST).read_text())
    except (OSError, ValueError) as exc:
        raise BackupError(f"{src} is not a ugvmap backup (no readable {MANIFEST}: {exc})"
                          ) from None
    if manifest.get("format") != FORMAT:
        raise BackupError(f"{src}: backup format {manifest.get('format')!r} is not {FORMAT}")
    return manifest


def verify(src: Path, manifest: dict[str, Any], progress: Progress | None = None) -> None:
    """Every file of the backup against its size and SHA-256 (before anything is restored)."""
    report = progress or (lambda step, done: None)
    entries = [{"path": manifest["database"]["file"], "bytes": manifest["database"]["bytes"],
                "sha256": manifest["database"]["sha256"], "root": src}]
    entries += [{**f, "root": src / RASTERS} for f in manifest["store"]["files"]]
    done = 0
    for entry in entries:
        path = entry["root"] / entry["path"]
        if not path.resolve().is_relative_to(src.resolve()):
            raise BackupError(f"manifest entry {entry['path']!r} points outside the backup")
        if not path.is_file():
            raise BackupError(f"{path} is missing from the backup")
        digest, size = sha256_copy(path)
        if (digest, size) != (entry["sha256"], entry["bytes"]):
            raise BackupError(f"{path} does not match the manifest (damaged backup)")
        done += size
        report(f"verified {entry['path']}", done)


def _check_empty(dsn: str) -> None:
    with psycopg.connect(dsn, autocommit=True) as conn:
        tables = [r[0] for r in conn.execute(
            "SELECT tablename FROM pg_tables WHERE schemaname = 'public' "
            "AND tablename <> 'spatial_ref_sys' ORDER BY 1 LIMIT 5")]
    if tables:
        raise BackupError(f"the target database is not empty (it has {', '.join(tables)}); "
                          "restore into a new, empty database")


def _place_files(src: Path, files: Iterable[dict[str, Any]], store: Path,
                 progress: Progress) -> list[Path]:
    """Copy the backup's COGs into ``store``; files already there with the same checksum are
    kept, different ones refuse the restore before anything is copied. Returns what it
    created, for the caller to remove if the database restore then fails."""
    todo = []
    for entry in files:
        dst = store / entry["path"]
        if dst.exists():
            if sha256_copy(dst)[0] != entry["sha256"]:
                raise BackupError(f"{dst} exists with different content; restore into an empty "
                                  "raster store (UGVMAP_RASTER_STORE)")
            continue
        todo.append(entry)
    created: list[Path] = []
    done = 0
    try:
        for entry in todo:
            dst = store / entry["path"]
            dst.parent.mkdir(parents=True, exist_ok=True)
            tmp = dst.with_name(f".{dst.name}.{uuid.uuid4().hex[:8]}.tmp")
            sha256_copy(src / RASTERS / entry["path"], tmp)
            tmp.rename(dst)
            created.append(dst)
            done += entry["bytes"]
            progress(f"copied {entry['path']}", done)
    except BaseException:
        for path in created:
            path.unlink(missing_ok=True)
        raise
    return created


def restore(src: Path, database_url: str, store_root: str,
            progress: Progress | None = None) -> Summary:
    """Restore the backup in ``src`` into an empty database and the raster store."""
    report = progress or (lambda step, done: None)
    manifest = read_manifest(src)
    if "://" in store_root:
        raise BackupError(f"the raster store {store_root} is not a local directory")
    dsn = libpq_dsn(database_url)
    _check_empty(dsn)
    verify(src, manifest, report)
    created = _place_files(src, manifest["store"]["files"], Path(store_root), report)
    try:
        report("restoring the database", 0)
        _run([_tool("pg_restore"), "--exit-on-error", "--single-transaction", "--no-owner",
              f"--dbname={dsn}", str(src / manifest["database"]["file"])])
    except BaseException:
        for path in created:
            path.unlink(missing_ok=True)
        raise
    migrate.upgrade(database_url)
    with psycopg.connect(dsn) as conn:
        counts = _counts(conn)
        # Jobs running when the snapshot was taken (this backup's own row among them) never
        # finish in the restored world.
        conn.execute("UPDATE ingest_jobs SET status = 'failed', finished_at = now(), "
                     "error = 'interrupted: restored from a backup taken while it ran' "
                     "WHERE status = 'running'")
        # The files are in this store now (migration 0009 records where they are).
        conn.execute("INSERT INTO raster_store (root) VALUES (%(root)s) ON CONFLICT (id) DO "
                     "UPDATE SET root = EXCLUDED.root, recorded_at = now()",
                     {"root": str(Path(store_root).resolve())})
    expected = manifest["database"]["counts"]
    if any(counts[t] != expected.get(t, counts[t]) for t in COUNTED):
        raise BackupError(f"restored row counts {counts} differ from the backup's {expected}")
    files = manifest["store"]["files"]
    return Summary(src, manifest["database"]["revision"], len(files),
                   sum(f["bytes"] for f in files), counts, len(manifest["store"]["external"]))
