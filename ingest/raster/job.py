"""The ``ingest raster`` job: validate every input, write the COGs, then register them.

Order matters for atomicity:

1. every input is validated first (nothing written if any is bad);
2. each COG is written under a temporary name and renamed when complete, then put into the
   raster store (:mod:`app.tiles.store`: in place for a directory, an upload for S3 that
   exists only once complete);
3. all catalogue rows (layer upsert, sources, new bounds/zooms, ``version + 1``) are
   committed in one transaction, only after every object exists (the layer overview is
   rendered and stored inside that transaction, before the commit);
4. if anything fails after step 2, the objects this job stored are deleted again.

A job killed between 2 and 3 leaves at most unregistered objects, which are never served
(tiles are only read from sources the catalogue lists) and which the next ingest into the
layer deletes (jobs on one layer are serialised by an advisory lock, so that is safe).
"""

from __future__ import annotations

import contextlib
import json
import re
import sys
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from sqlalchemy import Connection, text
from sqlalchemy.orm import Session
from tqdm import tqdm

from app.db.models import LAYER_KINDS, SLUG_RE
from app.db.session import get_engine, session_scope
from app.grid import ground_resolution_m, tile_bounds
from app.tiles.catalog import tile_sources
from app.tiles.store import RasterStore, deleting_files, open_store, remove_files
from ingest.raster.cog import measure_cog, write_cog
from ingest.raster.overview import build_overview
from ingest.raster.sources import Source, SourceError, inspect


@dataclass(frozen=True)
class WrittenSource:
    """One COG in the store, with what the catalogue needs to know about it."""

    name: str
    uri: str
    footprint_wkb: bytes
    width: int
    height: int
    band_count: int
    dtype: str
    zoom: int
    minzoom: int
    resolution_m: float
    meta: dict


@dataclass(frozen=True)
class IngestReport:
    """What an ingest did: the layer's new version and each COG written."""
    layer: str
    version: int
    sources: list[WrittenSource]


def write_source(source: Source, store: RasterStore, staging: Path, layer: str,
                 to_cog: Callable[[Source, Path], None] | None = None,
                 stored: list[str] | None = None) -> WrittenSource:
    """Write one validated source as a COG in ``staging``, measure what the catalogue needs,
    then put it into the store (its catalogue value is appended to ``stored`` first, so a
    caller can clean up after a failure at any point)."""
    key = f"{layer}/{uuid.uuid4().hex}.tif"
    dst = staging / key.rpartition("/")[2]
    if to_cog is None:
        write_cog(source.cog_input(), dst, source.dtype, len(source.bands))
    else:
        to_cog(source, dst)
    try:
        cog = measure_cog(dst)
        if cog.footprint is None:
            raise SourceError(f"{source.name}: no valid pixels (everything is nodata/transparent)")
        lat = (source.bounds_4326[1] + source.bounds_4326[3]) / 2
        meta = {"source_path": str(source.path.resolve()), "georef": source.georef_from,
                "source_crs": source.crs.to_string(), "zoom": cog.zoom, "minzoom": cog.minzoom,
                "bounds_4326": list(source.bounds_4326)}
        if cog.display_range:
            meta["display_range"] = cog.display_range
        if stored is not None:
            stored.append(store.ref(key))
        store.put(dst, key)
        return WrittenSource(name=source.name, uri=store.ref(key),
                             footprint_wkb=cog.footprint.wkb, width=cog.width,
                             height=cog.height, band_count=cog.band_count, dtype=cog.dtype,
                             zoom=cog.zoom, minzoom=cog.minzoom,
                             resolution_m=ground_resolution_m(cog.zoom, lat), meta=meta)
    except BaseException:
        dst.unlink(missing_ok=True)
        raise


def register(session: Session, written: Sequence[WrittenSource], layer: str,
             title: str | None, kind: str, priority: int, overview: Path,
             store: RasterStore) -> tuple[int, str | None]:
    """Upsert the layer, insert its new sources, render its new overview into the local file
    ``overview``, put it into the store as ``layer/<name>`` and point the layer at it, in the
    caller's transaction (so the layer changes at once, on commit; a queued job commits its
    own success with it); return the new version and the replaced overview (to delete)."""
    overview_ref = store.ref(f"{layer}/{overview.name}")
    old_overview = session.execute(
        text("SELECT overview_uri FROM layers WHERE slug = :slug FOR UPDATE"),
        {"slug": layer}).scalar()
    row = session.execute(text(
        "INSERT INTO layers (slug, title, kind, overview_uri) "
        "VALUES (:slug, :title, :kind, :overview) "
        "ON CONFLICT (slug) DO UPDATE SET title = COALESCE(:given_title, layers.title), "
        "  version = layers.version + 1, updated_at = now(), overview_uri = :overview "
        "RETURNING id, version"),
        {"slug": layer, "title": title or layer, "given_title": title, "kind": kind,
         "overview": overview_ref},
    ).one()
    layer_id, version = int(row[0]), int(row[1])
    for src in written:
        session.execute(text(
            "INSERT INTO raster_sources (layer_id, name, uri, footprint, priority, width, "
            " height, band_count, dtype, resolution_m, meta) VALUES (:layer_id, :name, :uri,"
            " ST_Multi(ST_SetSRID(ST_GeomFromWKB(:wkb), 3857)), :priority, :width, :height,"
            " :bands, :dtype, :res, CAST(:meta AS jsonb))"),
            {"layer_id": layer_id, "name": src.name, "uri": src.uri,
             "wkb": src.footprint_wkb, "priority": priority, "width": src.width,
             "height": src.height, "bands": src.band_count, "dtype": src.dtype,
             "res": src.resolution_m, "meta": json.dumps(src.meta)})
    session.execute(text(
        "UPDATE layers l SET "
        " bounds = (SELECT ST_Envelope(ST_Transform(ST_SetSRID(ST_Extent(s.footprint),"
        "   3857), 4326)) FROM raster_sources s WHERE s.layer_id = l.id),"
        " resolution_m = (SELECT min(resolution_m) FROM raster_sources s"
        "   WHERE s.layer_id = l.id),"
        " maxzoom = (SELECT max((meta->>'zoom')::int) FROM raster_sources s"
        "   WHERE s.layer_id = l.id),"
        " minzoom = (SELECT min((meta->>'minzoom')::int) FROM raster_sources s"
        "   WHERE s.layer_id = l.id) "
        "WHERE l.id = :id"), {"id": layer_id})
    render_overview(session.connection(), layer_id, layer, overview)
    store.put(overview, f"{layer}/{overview.name}")
    return version, old_overview


def render_overview(conn: Connection, layer_id: int, layer: str, dst: Path) -> None:
    """Render the layer, as this transaction sees it (new sources included), into ``dst``.

    The sources come from the tile query itself (every source meets the world tile), so the
    overview is painted in exactly the order tiles are.
    """
    sources = tile_sources(conn, layer, tile_bounds(0, 0, 0))
    row = conn.execute(text(
        "SELECT ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e), "
        " (SELECT maxzoom FROM layers WHERE id = :id) FROM (SELECT ST_Extent(footprint) AS e "
        " FROM raster_sources WHERE layer_id = :id) q"), {"id": layer_id}).one()
    assert sources is not None  # the layer row was upserted in this transaction
    build_overview(sources.sources, (row[0], row[1], row[2], row[3]), row[4], dst)


@contextlib.contextmanager
def layer_lock(layer: str, database_url: str | None = None) -> Iterator[None]:
    """Serialise ingests into one layer, so each overview sees every committed source.

    A session-level advisory lock: released explicitly, or by the server if the job dies.
    """
    with get_engine(database_url).connect() as conn:
        key = {"key": f"ugvmap.raster:{layer}"}
        conn.execute(text("SELECT pg_advisory_lock(hashtext(:key))"), key)
        conn.commit()
        try:
            yield
        finally:
            conn.execute(text("SELECT pg_advisory_unlock(hashtext(:key))"), key)
            conn.commit()


def sweep_leftovers(store: RasterStore, layer: str,
                    database_url: str | None = None) -> list[str]:
    """Delete objects under the layer's prefix in the store that the catalogue does not
    reference.

    Called under :func:`layer_lock`, so no other job is writing there: anything
    unreferenced (temporary files, or finished COGs of a job killed before its commit) is a
    leftover of a dead job and is never served.
    """
    present = store.refs_under(layer)
    if not present:
        return []
    engine = get_engine(database_url)
    with deleting_files(engine):  # a backup's snapshot may still name a file unreferenced now
        with engine.connect() as conn:
            refs: list[str] = list(conn.execute(text(
                "SELECT uri FROM raster_sources UNION SELECT overview_uri FROM layers "
                "WHERE overview_uri IS NOT NULL")).scalars())
        known = {store.resolve(ref) for ref in refs}
        stale = [ref for ref in present if store.resolve(ref) not in known]
        store.delete(stale)
    return stale


def ingest_raster(paths: Sequence[Path], layer: str, *, title: str | None = None,
                  kind: str = "orthophoto", crs: str | None = None, priority: int = 0,
                  inspect_source: Callable[[Path], Source] | None = None,
                  to_cog: Callable[[Source, Path], None] | None = None,
                  database_url: str | None = None,
                  store: RasterStore | Path | str | None = None,
                  on_progress: Callable[[float, str], None] | None = None,
                  after_register: Callable[[Session], None] | None = None) -> IngestReport:
    """Ingest ``paths`` into layer ``layer``; raise :class:`SourceError` on bad input.

    ``inspect_source``/``to_cog`` let the GCP path plug in its own georeferencing and warp;
    ``on_progress(fraction, step)`` is told before each step (e.g. to update a job row);
    ``after_register(session)`` writes rows that belong with the sources (an IPM drive's
    trajectory) in the registering transaction, after the layer row exists.
    """
    if not re.match(SLUG_RE, layer):
        raise SourceError(f"layer slug {layer!r} must match {SLUG_RE}")
    if kind not in LAYER_KINDS:
        raise SourceError(f"--kind must be one of {', '.join(LAYER_KINDS)}")
    raster_store = open_store(store)
    check = inspect_source or (lambda p: inspect(p, crs=crs))
    sources = [check(Path(p)) for p in paths]
    written: list[WrittenSource] = []
    created: list[str] = []
    bar = tqdm([*sources, None], desc=f"ingest {layer}", unit="step",
               disable=not sys.stderr.isatty())
    with layer_lock(layer, database_url), raster_store.staging(layer) as staging:
        sweep_leftovers(raster_store, layer, database_url)
        try:
            for done, source in enumerate(bar):
                bar.set_postfix_str(source.name if source else "layer overview")
                if on_progress:
                    on_progress(done / len(bar), source.name if source else "layer overview")
                if source is not None:
                    written.append(write_source(source, raster_store, staging, layer, to_cog,
                                                created))
            overview = staging / f"overview-{uuid.uuid4().hex}.tif"
            created.append(raster_store.ref(f"{layer}/{overview.name}"))
            with session_scope(database_url) as session:
                version, replaced = register(session, written, layer, title, kind, priority,
                                             overview, raster_store)
                if after_register is not None:
                    after_register(session)
        except BaseException:
            with contextlib.suppress(Exception):  # the original error matters more
                raster_store.delete(created)
            raise
    if replaced:
        remove_files(get_engine(database_url), [replaced], raster_store)
    return IngestReport(layer=layer, version=version, sources=written)
