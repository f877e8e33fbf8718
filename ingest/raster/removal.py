"""``ugvmap layers remove-source``: take one source out of a layer, leaving the others.

A source added by mistake (a file from another survey, another continent) would otherwise
only go with the whole layer. Like an ingest, the removal runs under the layer's lock
(:func:`~ingest.raster.job.layer_lock`), changes the catalogue in one transaction (the source
row gone, the layer's bounds, zooms and overview redone, its version bumped, so every
versioned tile URL changes) and deletes the source's COG and the old overview only after the
commit: a reader sees the layer before or after, never half.
"""

from __future__ import annotations

import contextlib
import uuid
from dataclasses import dataclass

from sqlalchemy import text

from app.db.session import get_engine, session_scope
from app.tiles.catalog import get_layer
from app.tiles.store import RasterStore, open_store, remove_files
from ingest.raster.job import LayerShape, layer_lock, refresh_layer
from ingest.raster.sources import SourceError


@dataclass(frozen=True)
class Removed:
    """The source taken out (id and name) and the layer it left."""

    layer: str
    source_id: int
    name: str
    shape: LayerShape

    def summary(self) -> str:
        """The command's report."""
        areas = f" in {self.shape.areas} separate areas" if self.shape.areas > 1 else ""
        return (f"removed source {self.source_id} ({self.name}) from layer {self.layer}: "
                f"version {self.shape.version}, {self.shape.sources} sources{areas}")


def remove_source(layer: str, source: str, database_url: str | None = None,
                  store: RasterStore | None = None) -> Removed:
    """Remove the source of layer ``layer`` whose id (as ``ugvmap layers show`` lists it) or
    file name is ``source``; raise :class:`SourceError` if there is none, if the name is not
    unique, or if it is the layer's only source (a layer without sources is no layer)."""
    raster_store = store or open_store()
    with get_engine(database_url).connect() as conn:  # before staging makes it a folder
        if get_layer(conn, layer) is None:
            raise SourceError(f"no raster layer {layer!r} (see `ugvmap layers list`)")
    with layer_lock(layer, database_url), raster_store.staging(layer) as staging:
        overview = staging / f"overview-{uuid.uuid4().hex}.tif"
        new_overview = raster_store.ref(f"{layer}/{overview.name}")
        try:
            with session_scope(database_url) as session:
                row = session.execute(text(
                    "SELECT id, overview_uri FROM layers WHERE slug = :slug FOR UPDATE"),
                    {"slug": layer}).first()
                if row is None:  # deleted meanwhile
                    raise SourceError(f"no raster layer {layer!r} (see `ugvmap layers list`)")
                rows = session.execute(text(
                    "SELECT id, name, uri, (SELECT count(*) FROM raster_sources "
                    "  WHERE layer_id = :layer) AS total FROM raster_sources "
                    "WHERE layer_id = :layer AND (name = :source OR id::text = :source) "
                    "ORDER BY id"), {"layer": row.id, "source": source}).all()
                if not rows:
                    raise SourceError(f"layer {layer} has no source {source!r} (ids and "
                                      f"names: `ugvmap layers show {layer}`)")
                if len(rows) > 1:
                    raise SourceError(
                        f"layer {layer} has {len(rows)} sources named {source!r} (ids "
                        f"{', '.join(str(r.id) for r in rows)}): give the id of the one to "
                        "remove")
                gone = rows[0]
                if gone.total == 1:
                    raise SourceError(
                        f"{gone.name} is layer {layer}'s only source: delete the layer with "
                        f"`ugvmap layers delete {layer}`")
                session.execute(text("DELETE FROM raster_sources WHERE id = :id"),
                                {"id": gone.id})
                version: int = session.execute(text(
                    "UPDATE layers SET version = version + 1, updated_at = now(), "
                    "overview_uri = :overview WHERE id = :id RETURNING version"),
                    {"id": row.id, "overview": new_overview}).scalar_one()
                shape = refresh_layer(session, row.id, layer, version, overview, raster_store)
        except BaseException:
            with contextlib.suppress(Exception):  # the original error matters more
                raster_store.delete([new_overview])
            raise
    remove_files(get_engine(database_url),
                 [gone.uri, *([row.overview_uri] if row.overview_uri else [])], raster_store)
    return Removed(layer, gone.id, gone.name, shape)
