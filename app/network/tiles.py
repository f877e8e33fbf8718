"""Mapbox vector tiles of a road network, rendered by PostGIS (``ST_AsMVT``).

Layers: ``segments`` (planner attributes) at every zoom, simplified to about a pixel below
zoom 14 so low-zoom tiles stay small; ``nodes`` (kind, traffic light) from zoom 12.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import Response
from sqlalchemy import text
from sqlalchemy.orm import Session

from app import errors
from app.errors import NotFoundError
from app.grid import TILE_SIZE, parse_tile, pixel_size_m
from app.network.collections import network_row
from app.network.tile_cache import Bounds, shared_cache
from app.network.tokens import SessionDep, read_access
from app.settings import get_settings

router = APIRouter(tags=["Vector tiles"], dependencies=[Depends(read_access)],
                   responses=errors.responses(
                       errors.InvalidParameterValueError, errors.NotFoundError,
                       errors.TileOutOfRangeError, errors.UnauthorizedError,
                       errors.ForbiddenError, errors.DatabaseUnavailableError))

MVT = "application/vnd.mapbox-vector-tile"
EXTENT = 4096
BUFFER = 64
NODES_MINZOOM = 12
SIMPLIFY_BELOW = 14

TILE_SQL = f"""
WITH bounds AS (
    SELECT ST_TileEnvelope(:z, :x, :y) AS tile,
           ST_Transform(ST_TileEnvelope(:z, :x, :y, margin => {BUFFER / EXTENT}), 4326) AS q
), segments AS (
    SELECT ST_AsMVTGeom(ST_Simplify(ST_Transform(s.geom, 3857), :tolerance), b.tile,
                        {EXTENT}, {BUFFER}, true) AS geom,
           s.id, s.name, s.road_class, s.oneway, s.lanes_forward, s.lanes_backward,
           s.speed_limit_kph, s.is_junction, s.surface, s.width_m, s.length_m, s.version
      FROM road_segments s, bounds b
     WHERE s.network_id = :network_id AND s.geom && b.q
), nodes AS (
    SELECT ST_AsMVTGeom(ST_Transform(n.geom, 3857), b.tile, {EXTENT}, {BUFFER}, true) AS geom,
           n.id, n.kind, n.traffic_light
      FROM road_nodes n, bounds b
     WHERE n.network_id = :network_id AND n.geom && b.q AND :z >= {NODES_MINZOOM}
)
SELECT COALESCE((SELECT ST_AsMVT(segments, 'segments', {EXTENT}, 'geom', 'id')
                   FROM segments WHERE geom IS NOT NULL), '')
    || COALESCE((SELECT ST_AsMVT(nodes, 'nodes', {EXTENT}, 'geom', 'id')
                   FROM nodes WHERE geom IS NOT NULL), '')
"""


def tile_bounds(session: Session, z: int, x: int, y: int) -> Bounds:
    """Lon/lat bounds of the tile plus its buffer: what an edit must meet to change it."""
    row = session.execute(text(
        f"SELECT ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e) FROM (SELECT ST_Transform("
        f"ST_TileEnvelope(:z, :x, :y, margin => {BUFFER / EXTENT}), 4326) AS e) q"),
        {"z": z, "x": x, "y": y}).one()
    return (row[0], row[1], row[2], row[3])


@router.get("/networks/{name}/tiles/{z}/{x}/{y}.mvt", response_class=Response,
            responses={200: {"content": {MVT: {}}}})
def network_tile(name: str, z: str, x: str, y: str, session: SessionDep) -> Response:
    """One Mapbox vector tile of the network (cached per worker until the network changes)."""
    zi, xi, yi = parse_tile(z, x, y)
    network = network_row(session, name)
    if network is None:
        raise NotFoundError(f"network {name[:100]!r} not found")
    cache = shared_cache(get_settings().database_url)
    key = (network.id, zi, xi, yi)
    tile = cache.get(key, network.version)
    status = "hit"
    if tile is None:
        status = "miss"
        tolerance = pixel_size_m(zi) * TILE_SIZE / EXTENT if zi < SIMPLIFY_BELOW else 0.0
        tile = bytes(session.execute(text(TILE_SQL), {
            "z": zi, "x": xi, "y": yi, "network_id": network.id,
            "tolerance": tolerance}).scalar_one())
        cache.put(key, network.version, tile_bounds(session, zi, xi, yi), tile)
    return Response(tile, media_type=MVT, headers={"X-Tile-Cache": status,
                                                   "Cache-Control": "no-cache"})
