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

A layer is one place: a source whose bounds neither overlap nor touch the layer's sources (or,
for a new layer, the first source given, and those connected to it) is refused unless
``add``: a file from another continent would otherwise stretch the layer's bounds across
it, unnoticed (:func:`refuse_far`).

Re-ingesting: a source is its input file's content (SHA-256, kept as the source's checksum).
A file whose content is already a source of the layer is refused (it would stack a duplicate,
drawn twice over itself) unless ``replace``: then every source of the layer with the same
content or the same file name is replaced by the new one, in the registering transaction,
and its COG deleted after the commit. A new file with a new name is a new source (a
re-survey drawn on top).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import re
import sys
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import shapely
from pyproj import Geod
from shapely.geometry import box
from shapely.geometry.base import BaseGeometry
from sqlalchemy import Connection, text
from sqlalchemy.orm import Session
from tqdm import tqdm

from app.db.models import LAYER_KINDS, SLUG_RE
from app.db.session import get_engine, session_scope
from app.grid import ground_resolution_m, tile_bounds
from app.tiles.catalog import tile_sources
from app.tiles.store import (
    RasterStore,
    claim_root,
    deleting_files,
    open_store,
    remove_files,
    store_root,
)
from ingest.raster.cog import measure_cog, write_cog
from ingest.raster.footprint import connected_areas
from ingest.raster.overview import build_overview
from ingest.raster.sources import Source, SourceError, as_elevation, inspect


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
    checksum: str = ""
    """``sha256:<hex>`` of the input file (what makes a re-ingest "the same file")."""


@dataclass(frozen=True)
class LayerShape:
    """A layer as a change left it: its version, how many sources, in how many separate
    areas (:func:`~ingest.raster.footprint.connected_areas` of their footprints)."""

    version: int
    sources: int
    areas: int


@dataclass(frozen=True)
class IngestReport:
    """What an ingest did: each COG written, and the layer it left."""
    layer: str
    version: int
    sources: list[WrittenSource]
    shape: LayerShape | None = None
    replaced: int = 0
    """How many sources of the layer the new ones replaced (``replace``)."""

    def summary(self) -> str:
        """The line that closes an ingest: the new version and, for a layer that had sources
        before, how many it has now (added, replaced); and how many separate areas, where
        more than one."""
        line = f"layer {self.layer} at version {self.version}"
        shape = self.shape
        if shape is None:
            return line
        added = len(self.sources)
        if shape.sources > added or self.replaced:
            line += (f": {shape.sources} sources ({added} added"
                     + (f", {self.replaced} replaced)" if self.replaced else ")"))
        if shape.areas > 1:
            line += f"{',' if shape.sources > added or self.replaced else ''} in {shape.areas} " \
                "separate areas"
        return line


def checksum(path: Path) -> str:
    """``sha256:<hex>`` of a file's content, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(1 << 20):
            digest.update(block)
    return f"sha256:{digest.hexdigest()}"


REPLACE_HINT = "re-ingest it in its place with --replace (POST /jobs: \"replace\": true)"


def refuse_duplicates(conn: Connection, layer: str, names: Sequence[str],
                      checksums: Sequence[str]) -> None:
    """Refuse files already among the layer's sources (same content), or given twice."""
    twice = sorted({n for n, c in zip(names, checksums, strict=True)
                    if checksums.count(c) > 1})
    if twice:
        raise SourceError(f"{', '.join(twice)}: the same file is given more than once")
    row = conn.execute(text(
        "SELECT s.id, s.name, s.checksum, s.ingested_at FROM raster_sources s JOIN layers l "
        "ON l.id = s.layer_id WHERE l.slug = :layer AND s.checksum = ANY(:sums) "
        "ORDER BY s.id LIMIT 1"), {"layer": layer, "sums": list(checksums)}).first()
    if row is not None:
        given = names[list(checksums).index(row.checksum)]
        raise SourceError(f"{given}: layer {layer} already has this file as source {row.id} "
                          f"({row.name}, ingested {row.ingested_at:%Y-%m-%d %H:%M}); "
                          f"{REPLACE_HINT}")


ADD_HINT = ("ingest it into a layer of its own (--layer NAME), or add it to this one as a "
            "separate area with --add (POST /jobs: \"add\": true)")


def _geometries(wkbs: Iterable[bytes]) -> list[BaseGeometry]:
    return [shapely.from_wkb(bytes(wkb)) for wkb in wkbs]


def refuse_far(conn: Connection, layer: str, names: Sequence[str],
               bounds_4326: Sequence[Sequence[float]]) -> None:
    """Refuse new sources (``names``, with their lon/lat bounds) that do not overlap or touch
    the layer's area: its sources' footprints, or for a new layer the first source given; a
    new source connected to the area through another new one is in it."""
    existing = _geometries(conn.execute(text(
        "SELECT ST_AsBinary(ST_Transform(s.footprint, 4326)) FROM raster_sources s "
        "JOIN layers l ON l.id = s.layer_id WHERE l.slug = :layer ORDER BY s.id"),
        {"layer": layer}).scalars())
    boxes = [box(*b) for b in bounds_4326]
    area = connected_areas([*existing, *boxes])
    home = set(area[:len(existing)]) if existing else {area[0]}
    far = [i for i, a in enumerate(area[len(existing):]) if a not in home]
    if not far:
        return
    place = shapely.union_all([g for g, a in zip([*existing, *boxes], area, strict=True)
                               if a in home])
    first = boxes[far[0]]
    centre, there = first.centroid, place.centroid
    _, _, metres = Geod(ellps="WGS84").inv(centre.x, centre.y, there.x, there.y)
    whose = (f"layer {layer}'s sources" if existing
             else f"{names[0]}, the first file given for the new layer {layer}")
    west, south, east, north = place.bounds
    raise SourceError(
        f"{', '.join(names[i] for i in far)}: lies at {centre.x:.4f},{centre.y:.4f}, "
        f"{metres / 1000:,.0f} km from the area of {whose} ({west:.4f},{south:.4f},"
        f"{east:.4f},{north:.4f}), touching none of it; {ADD_HINT}")


def write_source(source: Source, store: RasterStore, staging: Path, layer: str,
                 to_cog: Callable[[Source, Path], None] | None = None,
                 stored: list[str] | None = None, content: str | None = None) -> WrittenSource:
    """Write one validated source as a COG in ``staging``, measure what the catalogue needs,
    then put it into the store (its catalogue value is appended to ``stored`` first, so a
    caller can clean up after a failure at any point). ``content``: the input's
    :func:`checksum`, when the caller has it already."""
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
        if source.warnings:
            meta["warnings"] = source.warnings
        if stored is not None:
            stored.append(store.ref(key))
        store.put(dst, key)
        return WrittenSource(name=source.name, uri=store.ref(key),
                             footprint_wkb=cog.footprint.wkb, width=cog.width,
                             height=cog.height, band_count=cog.band_count, dtype=cog.dtype,
                             zoom=cog.zoom, minzoom=cog.minzoom,
                             resolution_m=ground_resolution_m(cog.zoom, lat), meta=meta,
                             checksum=content or checksum(source.path))
    except BaseException:
        dst.unlink(missing_ok=True)
        raise


@dataclass(frozen=True)
class Registered:
    """What :func:`register` did: the layer it left, and the store references it replaced
    (the old overview, replaced sources' COGs: to delete after the commit)."""

    shape: LayerShape
    replaced: list[str]
    replaced_sources: int


def register(session: Session, written: Sequence[WrittenSource], layer: str,
             title: str | None, kind: str, priority: int, overview: Path,
             store: RasterStore, replace: bool = False, add: bool = False) -> Registered:
    """Upsert the layer, insert its new sources (replacing, with ``replace``, those with the
    same content or file name; else refusing a duplicate; refusing, unless ``add``, those
    apart from the layer's area), render its new overview into the local file ``overview``,
    put it into the store as ``layer/<name>`` and point the layer at it, in the caller's
    transaction (so the layer changes at once, on commit; a queued job commits its own
    success with it)."""
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
    names, sums = [w.name for w in written], [w.checksum for w in written]
    replaced: list[str] = []
    if replace:
        replaced += session.execute(text(
            "DELETE FROM raster_sources WHERE layer_id = :id AND (checksum = ANY(:sums) "
            "OR name = ANY(:names)) RETURNING uri"),
            {"id": layer_id, "sums": sums, "names": names}).scalars()
    else:  # again, in the transaction: another ingest may have registered it meanwhile
        refuse_duplicates(session.connection(), layer, names, sums)
    if not add:
        refuse_far(session.connection(), layer, names,
                   [w.meta["bounds_4326"] for w in written])
    for src in written:
        session.execute(text(
            "INSERT INTO raster_sources (layer_id, name, uri, footprint, priority, width, "
            " height, band_count, dtype, resolution_m, meta, checksum) VALUES (:layer_id, "
            " :name, :uri, ST_Multi(ST_SetSRID(ST_GeomFromWKB(:wkb), 3857)), :priority, "
            " :width, :height, :bands, :dtype, :res, CAST(:meta AS jsonb), :checksum)"),
            {"layer_id": layer_id, "name": src.name, "uri": src.uri, "checksum": src.checksum,
             "wkb": src.footprint_wkb, "priority": priority, "width": src.width,
             "height": src.height, "bands": src.band_count, "dtype": src.dtype,
             "res": src.resolution_m, "meta": json.dumps(src.meta)})
    shape = refresh_layer(session, layer_id, layer, version, overview, store)
    return Registered(shape, [old_overview, *replaced] if old_overview else replaced,
                      len(replaced))


def refresh_layer(session: Session, layer_id: int, layer: str, version: int, overview: Path,
                  store: RasterStore) -> LayerShape:
    """After its sources changed: the layer's bounds, resolution and zooms from its sources,
    its overview rendered into the local file ``overview`` and put into the store as
    ``layer/<name>``; what it now is."""
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
    footprints = _geometries(session.execute(text(
        "SELECT ST_AsBinary(footprint) FROM raster_sources WHERE layer_id = :id"),
        {"id": layer_id}).scalars())
    return LayerShape(version, len(footprints), max(connected_areas(footprints)) + 1)


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
    build_overview(sources.sources, (row[0], row[1], row[2], row[3]), row[4], dst,
                   heights=sources.kind == "elevation")


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
                  after_register: Callable[[Session], None] | None = None,
                  replace: bool = False, add: bool = False) -> IngestReport:
    """Ingest ``paths`` into layer ``layer``; raise :class:`SourceError` on bad input,
    including a file already in the layer unless ``replace``, and one apart from the layer's
    area unless ``add`` (module docstring).

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
    if raster_store.root == store_root():  # relative references: the database's own store
        with get_engine(database_url).begin() as conn:
            claim_root(conn)
    check = inspect_source or (lambda p: inspect(p, crs=crs))
    sources = [check(Path(p)) for p in paths]
    if kind == "elevation":
        sources = [as_elevation(source) for source in sources]
    sums = [checksum(source.path) for source in sources]
    with get_engine(database_url).connect() as conn:
        if not replace:
            refuse_duplicates(conn, layer, [s.name for s in sources], sums)
        if not add:
            refuse_far(conn, layer, [s.name for s in sources], [s.bounds_4326 for s in sources])
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
                                                created, sums[done]))
            overview = staging / f"overview-{uuid.uuid4().hex}.tif"
            created.append(raster_store.ref(f"{layer}/{overview.name}"))
            with session_scope(database_url) as session:
                registered = register(session, written, layer, title, kind, priority,
                                      overview, raster_store, replace, add)
                if after_register is not None:
                    after_register(session)
        except BaseException:
            with contextlib.suppress(Exception):  # the original error matters more
                raster_store.delete(created)
            raise
    if registered.replaced:
        remove_files(get_engine(database_url), registered.replaced, raster_store)
    return IngestReport(layer=layer, version=registered.shape.version, sources=written,
                        shape=registered.shape, replaced=registered.replaced_sources)
