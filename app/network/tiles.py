"""Mapbox vector tiles of a road network, rendered by PostGIS (``ST_AsMVT``).

Layers: ``segments``, ``nodes`` (kind, traffic light; from zoom 12) and ``lanes`` (the
painted lane boundaries of ``ugvmap ingest lanes``: kind, colour, position, source; from zoom
16, where a 3 m lane is a few pixels wide). What ``segments``
holds depends on the zoom, so that a low-zoom tile of a country-sized network stays small:

- z >= 12: every segment with its planner attributes (simplified to about a pixel below 14);
- z 10-11: the same per-segment features, main roads only (:data:`CLASSES_BELOW`, no
  residential/service/track streets);
- z < 10: *generalised*: the roads of each shown class merged into one line feature per class,
  simplified to a pixel, with only ``road_class`` and ``segments`` (how many were merged) as
  properties: motorway/trunk/primary below z8, plus secondary, tertiary and the main links at
  z8-9. Read from ``road_overview`` (migration ``0003_netscale``: main roads pre-merged per
  class and 20 km cell, kept current by a trigger in each edit's transaction), so a z6 tile of
  a country reads a few dozen rows, not every main-road segment.

Features go into a tile ordered by id (lines merged from ``road_overview`` by their cell), not
in whatever order the scan returns the rows: a restored database, an UPDATE or a VACUUM FULL
stores them in another physical order, and the same network must give the same tile bytes
(``tests/test_backup.py`` compares them). The sort is over one tile's rows only.

The endpoint is :mod:`app.network.tiles_router`.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.grid import TILE_SIZE, pixel_size_m
from app.network.tile_cache import Bounds
from app.tiles.versioned import version_token

MVT = "application/vnd.mapbox-vector-tile"
EXTENT = 4096
BUFFER = 64
NODES_MINZOOM = 12
LANES_MINZOOM = 16
SIMPLIFY_BELOW = 14
MERGE_BELOW = 10
_MAJOR = ("motorway", "trunk", "primary")
# road_overview (migration 0003_netscale, MAIN_CLASSES) holds exactly these, for z < 10.
_MAIN = (*_MAJOR, "secondary", "tertiary", "motorway_link", "trunk_link", "primary_link")
CLASSES_BELOW: tuple[tuple[int, tuple[str, ...]], ...] = (
    (8, _MAJOR),
    (10, _MAIN),
    (12, (*_MAIN, "secondary_link", "tertiary_link", "unclassified")),
)
"""(zoom, classes): below that zoom only those road classes are drawn (first match wins)."""

_BOUNDS = f"""
WITH bounds AS (
    SELECT ST_TileEnvelope(:z, :x, :y) AS tile,
           ST_Transform(ST_TileEnvelope(:z, :x, :y, margin => {BUFFER / EXTENT}), 4326) AS q
)"""
_CLASS_FILTER = ("(CAST(:classes AS text[]) IS NULL "
                 "OR s.road_class = ANY(CAST(:classes AS text[])))")

TILE_SQL = f"""{_BOUNDS}, segments AS (
    SELECT ST_AsMVTGeom(ST_Simplify(ST_Transform(s.geom, 3857), :tolerance), b.tile,
                        {EXTENT}, {BUFFER}, true) AS geom,
           s.id, s.name, s.road_class, s.oneway, s.lanes_forward, s.lanes_backward,
           s.speed_limit_kph, s.is_junction, s.surface, s.width_m, s.length_m, s.version,
           s.confidence
      FROM road_segments s, bounds b
     WHERE s.network_id = :network_id AND s.geom && b.q AND {_CLASS_FILTER}
), nodes AS (
    SELECT ST_AsMVTGeom(ST_Transform(n.geom, 3857), b.tile, {EXTENT}, {BUFFER}, true) AS geom,
           n.id, n.kind, n.traffic_light
      FROM road_nodes n, bounds b
     WHERE n.network_id = :network_id AND n.geom && b.q AND :z >= {NODES_MINZOOM}
), lanes AS (
    SELECT ST_AsMVTGeom(ST_Transform(l.geom, 3857), b.tile, {EXTENT}, {BUFFER}, true) AS geom,
           l.id, l.segment_id, l.kind, l.colour, l.position, l.source, l.width_m,
           l.confidence, l.version
      FROM lane_boundaries l, bounds b
     WHERE l.network_id = :network_id AND l.geom && b.q AND :z >= {LANES_MINZOOM}
)
SELECT COALESCE((SELECT ST_AsMVT(segments, 'segments', {EXTENT}, 'geom', 'id' ORDER BY id)
                   FROM segments WHERE geom IS NOT NULL), '')
    || COALESCE((SELECT ST_AsMVT(nodes, 'nodes', {EXTENT}, 'geom', 'id' ORDER BY id)
                   FROM nodes WHERE geom IS NOT NULL), '')
    || COALESCE((SELECT ST_AsMVT(lanes, 'lanes', {EXTENT}, 'geom', 'id' ORDER BY id)
                   FROM lanes WHERE geom IS NOT NULL), '')
"""

OVERVIEW_SQL = f"""{_BOUNDS}, merged AS (
    SELECT o.road_class, sum(o.segments)::int AS segments,
           ST_Simplify(ST_LineMerge(ST_CollectionExtract(
               ST_Collect(o.geom ORDER BY o.cx, o.cy), 2)), :tolerance) AS g
      FROM road_overview o, bounds b
     WHERE o.network_id = :network_id AND o.geom && ST_Expand(b.tile, :margin)
       AND o.road_class = ANY(CAST(:classes AS text[]))
     GROUP BY o.road_class
), overview AS (
    SELECT ST_AsMVTGeom(m.g, b.tile, {EXTENT}, {BUFFER}, true) AS geom,
           row_number() OVER (ORDER BY m.road_class) AS id, m.road_class, m.segments
      FROM merged m, bounds b
)
SELECT COALESCE((SELECT ST_AsMVT(overview, 'segments', {EXTENT}, 'geom', 'id' ORDER BY id)
                   FROM overview WHERE geom IS NOT NULL), '')
"""


def zoom_params(z: int) -> dict[str, object]:
    """The tile queries' per-zoom parameters: simplification tolerance (about one tile pixel
    below z14), the buffer margin in metres and the road classes drawn."""
    tile_m = pixel_size_m(z) * TILE_SIZE
    return {"z": z, "tolerance": tile_m / EXTENT if z < SIMPLIFY_BELOW else 0.0,
            "margin": tile_m * BUFFER / EXTENT, "classes": shown_classes(z)}


def shown_classes(z: int) -> list[str] | None:
    """Road classes drawn at zoom ``z`` (None: all)."""
    return next((list(classes) for below, classes in CLASSES_BELOW if z < below), None)


def network_token(network: Any) -> str:
    """The version token of the network's tile URLs (a :func:`network_row` row): what a
    network TileJSON appends as ``?v=``."""
    return version_token("network", network.id, network.version, network.created_at)


def render_tile(session: Session, network_id: int, z: int, x: int, y: int) -> bytes:
    """Vector tile z/x/y of a network, as served (uncompressed MVT; empty when nothing is in
    it). The offline package writes the same bytes."""
    return bytes(session.execute(text(OVERVIEW_SQL if z < MERGE_BELOW else TILE_SQL),
                                 {**zoom_params(z), "x": x, "y": y,
                                  "network_id": network_id}).scalar_one())


def tile_bounds(session: Session, z: int, x: int, y: int) -> Bounds:
    """Lon/lat bounds of the tile plus its buffer: what an edit must meet to change it."""
    row = session.execute(text(
        f"SELECT ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e) FROM (SELECT ST_Transform("
        f"ST_TileEnvelope(:z, :x, :y, margin => {BUFFER / EXTENT}), 4326) AS e) q"),
        {"z": z, "x": x, "y": y}).one()
    return (row[0], row[1], row[2], row[3])
