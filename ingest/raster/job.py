"""The ``ingest raster`` job: validate every input, write the COGs, then register them.

Order matters for atomicity:

1. every input is validated first (nothing written if any is bad);
2. each COG is written under a temporary name and renamed when complete;
3. all catalogue rows (layer upsert, sources, new bounds/zooms, ``version + 1``) are
   committed in one transaction, only after every file exists;
4. if anything fails after step 2, the files this job wrote are deleted again.

A job killed between 2 and 3 leaves at most unregistered files, which are never served
(tiles are only read from sources the catalogue lists) and which the next ingest into the
layer deletes (jobs on one layer are serialised by an advisory lock, so that is safe).
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import sys
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
import shapely.wkb
from sqlalchemy import text
from tqdm import tqdm

from app.db.models import LAYER_KINDS, SLUG_RE
from app.db.session import get_engine, session_scope
from app.settings import get_settings
from app.tiles.catalog import TileSource
from ingest.raster.cog import write_cog
from ingest.raster.footprint import footprint_3857
from ingest.raster.overview import build_overview
from ingest.raster.sources import Source, SourceError, inspect

EARTH_CIRCUMFERENCE_M = 2 * math.pi * 6378137.0


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
    layer: str
    version: int
    sources: list[WrittenSource]


def ground_resolution_m(zoom: int, lat: float) -> float:
    """Metres per pixel of a 256 px XYZ tile at ``zoom`` and latitude ``lat``."""
    return EARTH_CIRCUMFERENCE_M / (256 * 2**zoom) * math.cos(math.radians(lat))


def band_ranges(path: str, dtype: str) -> list[list[float]] | None:
    """Per-band display range (2nd-98th percentile) for non-8-bit data, from an overview."""
    if dtype == "uint8":
        return None
    with rasterio.open(path) as ds:
        scale = max(1, math.ceil(max(ds.width, ds.height) / 1024))
        shape = (ds.count, math.ceil(ds.height / scale), math.ceil(ds.width / scale))
        data = ds.read(out_shape=shape, masked=True)
    ranges = []
    for band in data[: 3 if data.shape[0] >= 3 else 1]:
        valid = band.compressed()
        lo, hi = (float(v) for v in np.percentile(valid, [2, 98])) if valid.size else (0, 1)
        ranges.append([lo, hi if hi > lo else lo + 1])
    return ranges


def write_source(source: Source, store: Path, layer: str,
                 to_cog: Callable[[Source, Path], None] | None = None) -> WrittenSource:
    """Write one validated source into the store and measure what the catalogue needs."""
    dst = store / layer / f"{uuid.uuid4().hex}.tif"
    if to_cog is None:
        write_cog(source.cog_input(), dst, source.dtype, len(source.bands))
    else:
        to_cog(source, dst)
    try:
        outline = footprint_3857(str(dst))
        if outline is None:
            raise SourceError(f"{source.name}: no valid pixels (everything is nodata/transparent)")
        with rasterio.open(dst) as ds:
            zoom = int(ds.tags(ns="TILING_SCHEME").get("ZOOM_LEVEL", 0))
            width, height, count, dtype = ds.width, ds.height, ds.count, ds.dtypes[0]
            minzoom = max(0, zoom - len(ds.overviews(1)))
        lat = (source.bounds_4326[1] + source.bounds_4326[3]) / 2
        meta = {"source_path": str(source.path.resolve()), "georef": source.georef_from,
                "source_crs": source.crs.to_string(), "zoom": zoom,
                "bounds_4326": list(source.bounds_4326)}
        ranges = band_ranges(str(dst), dtype)
        if ranges:
            meta["display_range"] = ranges
        return WrittenSource(name=source.name, uri=str(dst), footprint_wkb=outline.wkb,
                             width=width, height=height, band_count=count, dtype=dtype,
                             zoom=zoom, minzoom=minzoom,
                             resolution_m=ground_resolution_m(zoom, lat), meta=meta)
    except BaseException:
        dst.unlink(missing_ok=True)
        raise


def register(written: Sequence[WrittenSource], layer: str, title: str | None, kind: str,
             priority: int, overview_uri: str,
             database_url: str | None = None) -> tuple[int, str | None]:
    """Upsert the layer, insert its new sources and point it at its new overview, in one
    transaction; return the new version and the replaced overview file (to delete)."""
    with session_scope(database_url) as session:
        old_overview = session.execute(
            text("SELECT overview_uri FROM layers WHERE slug = :slug FOR UPDATE"),
            {"slug": layer}).scalar()
        layer_id, version = session.execute(text(
            "INSERT INTO layers (slug, title, kind, overview_uri) "
            "VALUES (:slug, :title, :kind, :overview) "
            "ON CONFLICT (slug) DO UPDATE SET title = COALESCE(:given_title, layers.title), "
            "  version = layers.version + 1, updated_at = now(), overview_uri = :overview "
            "RETURNING id, version"),
            {"slug": layer, "title": title or layer, "given_title": title, "kind": kind,
             "overview": overview_uri},
        ).one()
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
            " minzoom = :minzoom "
            "WHERE l.id = :id"),
            {"id": layer_id, "minzoom": min(src.minzoom for src in written)})
        return int(version), old_overview


def layer_overview(written: Sequence[WrittenSource], layer: str, priority: int, store: Path,
                   database_url: str | None = None) -> str:
    """Render the layer as it will be once ``written`` is registered into a new overview COG."""
    with session_scope(database_url) as session:
        rows = session.execute(text(
            "SELECT s.uri, s.meta->'display_range', s.priority, (meta->>'zoom')::int, "
            " ST_XMin(s.footprint), ST_YMin(s.footprint), ST_XMax(s.footprint), "
            " ST_YMax(s.footprint) FROM raster_sources s JOIN layers l ON l.id = s.layer_id "
            "WHERE l.slug = :slug ORDER BY s.priority, s.ingested_at, s.id"),
            {"slug": layer}).all()
    # Paint order as the tile query will have it: priority, then new sources after old ones.
    ordered = [(r[2], 0, i, TileSource(r[0], r[1])) for i, r in enumerate(rows)]
    ordered += [(priority, 1, i, TileSource(w.uri, w.meta.get("display_range")))
                for i, w in enumerate(written)]
    boxes = [r[4:8] for r in rows] + [shapely.wkb.loads(w.footprint_wkb).bounds
                                      for w in written]
    bounds = (min(b[0] for b in boxes), min(b[1] for b in boxes),
              max(b[2] for b in boxes), max(b[3] for b in boxes))
    maxzoom = max([r[3] for r in rows] + [w.zoom for w in written])
    dst = store / layer / f"overview-{uuid.uuid4().hex}.tif"
    build_overview([t[3] for t in sorted(ordered, key=lambda t: t[:3])], bounds, maxzoom, dst)
    return str(dst)


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


def sweep_leftovers(layer_dir: Path, database_url: str | None = None) -> list[Path]:
    """Delete files in a layer's store folder that the catalogue does not reference.

    Called under :func:`layer_lock`, so no other job is writing there: anything
    unreferenced (temporary files, or finished COGs of a job killed before its commit) is a
    leftover of a dead job and is never served.
    """
    if not layer_dir.is_dir():
        return []
    with get_engine(database_url).connect() as conn:
        known = set(conn.execute(text(
            "SELECT uri FROM raster_sources UNION SELECT overview_uri FROM layers "
            "WHERE overview_uri IS NOT NULL")).scalars())
    stale = [p for p in layer_dir.iterdir() if p.is_file() and str(p) not in known]
    for path in stale:
        path.unlink(missing_ok=True)
    return stale


def ingest_raster(paths: Sequence[Path], layer: str, *, title: str | None = None,
                  kind: str = "orthophoto", crs: str | None = None, priority: int = 0,
                  inspect_source: Callable[[Path], Source] | None = None,
                  to_cog: Callable[[Source, Path], None] | None = None,
                  database_url: str | None = None,
                  store: Path | None = None) -> IngestReport:
    """Ingest ``paths`` into layer ``layer``; raise :class:`SourceError` on bad input.

    ``inspect_source``/``to_cog`` let the GCP path plug in its own georeferencing and warp.
    """
    if not re.match(SLUG_RE, layer):
        raise SourceError(f"layer slug {layer!r} must match {SLUG_RE}")
    if kind not in LAYER_KINDS:
        raise SourceError(f"--kind must be one of {', '.join(LAYER_KINDS)}")
    store = store or Path(get_settings().raster_store_uri)
    check = inspect_source or (lambda p: inspect(p, crs=crs))
    sources = [check(Path(p)) for p in paths]
    written: list[WrittenSource] = []
    created: list[str] = []
    bar = tqdm([*sources, None], desc=f"ingest {layer}", unit="step",
               disable=not sys.stderr.isatty())
    with layer_lock(layer, database_url):
        sweep_leftovers(store / layer, database_url)
        try:
            for source in bar:
                bar.set_postfix_str(source.name if source else "layer overview")
                if source is not None:
                    written.append(write_source(source, store, layer, to_cog))
                    created.append(written[-1].uri)
            created.append(layer_overview(written, layer, priority, store, database_url))
            version, replaced = register(written, layer, title, kind, priority, created[-1],
                                         database_url)
        except BaseException:
            for uri in created:
                with contextlib.suppress(FileNotFoundError):
                    Path(uri).unlink()
            raise
    if replaced:
        Path(replaced).unlink(missing_ok=True)
    return IngestReport(layer=layer, version=version, sources=written)
