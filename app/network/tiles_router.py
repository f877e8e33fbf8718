"""The vector-tile endpoint of a road network: ``/networks/{name}/tiles/{z}/{x}/{y}.mvt``.

Tiles are rendered by :mod:`app.network.tiles` and kept per worker until the network changes
(:mod:`app.network.tile_cache`). HTTP caching follows :mod:`app.tiles.versioned`:
``?v=<network_token>`` (the network's current version) makes a tile immutable; without it, or
with an older token, ``no-cache``.
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response

from app import errors
from app.api.conditional import cache_headers, not_modified
from app.api.dependencies import SessionDep, read_access
from app.api.errors import responses
from app.api.query import only_query
from app.errors import NotFoundError
from app.grid import parse_tile
from app.network.collections import network_row
from app.network.tile_cache import shared_cache
from app.network.tiles import MVT, network_token, render_tile, tile_bounds
from app.params import NetworkName, TileXY, TileZ
from app.settings import get_settings
from app.tiles.versioned import VERSION_PARAM

router = APIRouter(tags=["Vector tiles"], dependencies=[Depends(read_access)],
                   responses=responses(
                       errors.InvalidParameterValueError, errors.NotFoundError,
                       errors.TileOutOfRangeError, errors.UnauthorizedError,
                       errors.ForbiddenError, errors.DatabaseUnavailableError))


@router.get("/networks/{name}/tiles/{z}/{x}/{y}.mvt", response_class=Response,
            dependencies=[only_query(VERSION_PARAM)],
            responses={200: {"content": {MVT: {}}}})
def network_tile(name: NetworkName, z: TileZ, x: TileXY, y: TileXY, session: SessionDep,
                 request: Request) -> Response:
    """One Mapbox vector tile of the network (cached per worker until the network changes;
    immutable for HTTP caches with the network's current ``?v=`` token)."""
    zi, xi, yi = parse_tile(z, x, y)
    network = network_row(session, name)
    if network is None:
        raise NotFoundError(f"network {name[:100]!r} not found")
    headers = cache_headers(request, network_token(network), "no-cache",
                            public=get_settings().network_read_role is None)
    unchanged = not_modified(request, headers)
    if unchanged is not None:
        return unchanged
    cache = shared_cache(get_settings().database_url)
    key = (network.id, zi, xi, yi)
    tile = cache.get(key, network.version)
    status = "hit"
    if tile is None:
        status = "miss"
        tile = render_tile(session, network.id, zi, xi, yi)
        cache.put(key, network.version, tile_bounds(session, zi, xi, yi), tile)
    return Response(tile, media_type=MVT, headers={**headers, "X-Tile-Cache": status})
