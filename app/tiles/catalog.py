"""Catalogue queries for raster layers, shared by the HTTP routes and ``ugvmap layers``.

The tile query does two things in one round trip: it reads the layer's version (for the ETag)
and asks PostGIS which source footprints meet the tile, in :data:`PAINT_ORDER`. The layer
overview written at ingest is rendered from the same query, so it paints like the tiles.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import Connection, text

from app.tiles.versioned import version_token

LAYER_COLUMNS = (
    "l.id, l.slug, l.title, l.kind, l.minzoom, l.maxzoom, l.resolution_m, l.attribution, "
    "l.version, l.created_at, l.updated_at, l.overview_uri, "
    "CASE WHEN l.bounds IS NULL THEN NULL ELSE ARRAY[ST_XMin(l.bounds), ST_YMin(l.bounds), "
    "ST_XMax(l.bounds), ST_YMax(l.bounds)] END AS bounds, "
    "(SELECT count(*) FROM raster_sources s WHERE s.layer_id = l.id) AS source_count"
)
#: The paint order of a layer's sources (alias ``s``), bottom first: lower ``--priority``
#: under higher, then older under newer, so a re-survey covers what it replaces. The one
#: definition, used by tiles, the layer overview, ``GET /layers/{slug}`` and ``layers show``.
PAINT_ORDER = "s.priority, s.ingested_at, s.id"
# Store references are relative to the raster store (app.tiles.store) and are returned as
# stored: whoever opens a file resolves it (``open_store().resolve``), so the catalogue never
# hands out server paths and a restored database works with any store location.


@dataclass(frozen=True)
class TileSource:
    """A source COG to paint, with the stretch non-8-bit data needs."""
    uri: str
    display_range: list[list[float]] | None


@dataclass(frozen=True)
class TileQuery:
    """What a tile needs from the catalogue: the layer's identity and version (ETag) and its sources
    meeting the tile, in paint order."""
    layer_id: int
    version: int
    created_at: datetime
    sources: list[TileSource]
    overview_uri: str | None
    kind: str = "orthophoto"  # elevation layers are drawn as relief (app.tiles.elevation)

    @property
    def token(self) -> str:
        """The version token of tile URLs (:mod:`app.tiles.versioned`)."""
        return layer_token(self.layer_id, self.version, self.created_at)


def layer_token(layer_id: int, version: int, created_at: datetime) -> str:
    """The version token naming this version of a raster layer."""
    return version_token("layer", layer_id, version, created_at)


def tile_sources(conn: Connection, slug: str,
                 bbox: tuple[float, float, float, float]) -> TileQuery | None:
    """The layer's version and the sources meeting ``bbox`` (EPSG:3857), bottom first."""
    rows = conn.execute(text(
        "SELECT l.id, l.version, l.created_at, l.overview_uri, s.uri, s.meta->'display_range', "
        " l.kind "
        "FROM layers l "
        "LEFT JOIN raster_sources s ON s.layer_id = l.id "
        " AND ST_Intersects(s.footprint, ST_MakeEnvelope(:x0, :y0, :x1, :y1, 3857)) "
        f"WHERE l.slug = :slug ORDER BY {PAINT_ORDER}"),
        {"slug": slug, "x0": bbox[0], "y0": bbox[1], "x1": bbox[2], "y1": bbox[3]},
    ).all()
    if not rows:
        return None
    sources = [TileSource(r[4], r[5]) for r in rows if r[4] is not None]
    return TileQuery(layer_id=rows[0][0], version=rows[0][1], created_at=rows[0][2],
                     sources=sources, overview_uri=rows[0][3], kind=rows[0][6])


def list_layers(conn: Connection) -> list[dict[str, Any]]:
    """Every layer's row, by slug."""
    rows = conn.execute(text(f"SELECT {LAYER_COLUMNS} FROM layers l ORDER BY l.slug"))
    return [dict(r._mapping) for r in rows]


def layer_row(conn: Connection, slug: str) -> dict[str, Any] | None:
    """The layer's own row, without its sources (TileJSON, existence checks)."""
    row = conn.execute(text(f"SELECT {LAYER_COLUMNS} FROM layers l WHERE l.slug = :slug"),
                       {"slug": slug}).first()
    return None if row is None else dict(row._mapping)


def get_layer(conn: Connection, slug: str) -> dict[str, Any] | None:
    """The layer and its sources (paint order)."""
    layer = layer_row(conn, slug)
    if layer is None:
        return None
    sources = conn.execute(text(
        "SELECT s.id, s.name, s.uri, s.priority, s.ingested_at, s.width, s.height, s.band_count,"
        " s.dtype, s.resolution_m, s.meta->>'georef' AS georef, (s.meta->>'zoom')::int AS zoom "
        f"FROM raster_sources s WHERE s.layer_id = :id ORDER BY {PAINT_ORDER}"),
        {"id": layer["id"]})
    layer["sources"] = [dict(s._mapping) for s in sources]
    return layer


def source_uri(conn: Connection, slug: str, source_id: int) -> str | None:
    """The stored COG of one of the layer's sources, or None."""
    return conn.execute(text(
        "SELECT s.uri FROM raster_sources s JOIN layers l ON l.id = s.layer_id "
        "WHERE l.slug = :slug AND s.id = :id"), {"slug": slug, "id": source_id}).scalar()


def delete_layer(conn: Connection, slug: str) -> list[str] | None:
    """Delete a layer and its source rows; return the files to remove after commit."""
    row = conn.execute(text("SELECT id, overview_uri FROM layers WHERE slug = :slug FOR UPDATE"),
                       {"slug": slug}).first()
    if row is None:
        return None
    uris: list[str] = list(conn.execute(
        text("SELECT uri FROM raster_sources WHERE layer_id = :id"), {"id": row.id}).scalars())
    conn.execute(text("DELETE FROM layers WHERE id = :id"), {"id": row.id})
    return uris + ([row.overview_uri] if row.overview_uri else [])
