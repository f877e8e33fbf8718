"""How clients find the networks' vector tiles: the ``/networks`` listing, and per network
its TileJSON, MapLibre style and GDAL ``metadata.json`` (built by :mod:`app.network.tilejson`).
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel
from sqlalchemy import text
from sqlalchemy.orm import Session

from app import errors
from app.api.dependencies import SessionDep, read_access
from app.api.errors import responses
from app.api.query import only_query
from app.network import tilejson as tj
from app.network.features_router import READ_ERRORS, base_url
from app.network.summary import NETWORKS_SQL, integer_ranges
from app.network.tiles import network_token
from app.network.tiles_router import network_tile
from app.params import NetworkName
from app.tiles.versioned import VERSION_PARAM, versioned

router = APIRouter(tags=["Vector tiles"], dependencies=[Depends(read_access)],
                   responses=responses(*READ_ERRORS))
NO_CACHE = {"Cache-Control": "no-cache"}  # they name the network's version, which edits bump
# A network name that is not a valid slug is 400, an unknown one 404.
NOT_FOUND = responses(errors.NotFoundError, errors.InvalidParameterValueError)
class NetworkLinks(BaseModel):
    """Where a network's parts are."""

    self: str
    tilejson: str
    style: str
    tiles: str
    metadata: str
    segments: str
    nodes: str
    route: str


class NetworkEntry(BaseModel):
    """One network as ``/networks`` lists it."""

    name: str
    title: str | None
    description: str | None
    version: int
    updated_at: str
    segment_count: int
    node_count: int
    bounds: list[float] | None
    links: NetworkLinks


class NetworkList(BaseModel):
    """The ``/networks`` document."""

    networks: list[NetworkEntry]


def _rows(session: Session, name: str | None) -> list[Any]:
    return list(session.execute(text(NETWORKS_SQL), {"name": name}).all())


def _info(row: Any) -> tj.NetworkInfo:
    bounds = None if row[8] is None else [float(v) for v in row[8:12]]
    return tj.NetworkInfo(row.name, row.title, row.description, row.version, bounds)


def _one(session: Session, name: str) -> Any:
    rows = _rows(session, name[:200])
    if not rows:
        raise errors.NotFoundError(f"network {name[:100]!r} not found")
    return rows[0]


def network_url(request: Request, name: str) -> str:
    """The network's own URL, under which its tiles, TileJSON and route service live."""
    return f"{base_url(request)}/networks/{name}"


def tiles_url(request: Request, row: Any) -> str:
    """The {z}/{x}/{y} template of the network's vector tiles, naming its current version
    (``?v=``), so HTTP caches may keep each tile forever (:mod:`app.tiles.versioned`)."""
    return versioned(f"{network_url(request, row.name)}/tiles/{{z}}/{{x}}/{{y}}.mvt",
                     network_token(row))


def _entry(request: Request, row: Any) -> dict[str, Any]:
    own = network_url(request, row.name)
    info = _info(row)
    collections = f"{base_url(request)}/collections/{row.name}"
    return {
        "name": row.name, "title": row.title, "description": row.description,
        "version": row.version, "updated_at": row.updated_at.isoformat(),
        "segment_count": row.segments, "node_count": row.nodes, "bounds": info.bounds,
        "links": {"self": own, "tilejson": f"{own}/tilejson.json", "style": f"{own}/style.json",
                  "tiles": tiles_url(request, row),
                  "metadata": f"{own}/tiles/metadata.json",
                  "segments": f"{collections}-segments", "nodes": f"{collections}-nodes",
                  "route": f"{own}/route"},
    }


@router.get("/networks", response_model=None, responses={200: {"model": NetworkList}})
def networks(request: Request, session: SessionDep) -> dict[str, Any]:
    """Every network with its size, extent, version and the links to its tiles and data."""
    return {"networks": [_entry(request, row) for row in _rows(session, None)]}


@router.get("/networks/{name}", response_model=None,
            responses={200: {"model": NetworkEntry}, **NOT_FOUND})
def network(name: NetworkName, request: Request, session: SessionDep) -> dict[str, Any]:
    """One network as the listing shows it."""
    return _entry(request, _one(session, name))


@router.get("/networks/{name}/tilejson.json", response_model=None, dependencies=[only_query()],
            responses={200: {"content": {"application/json": {"schema": {"type": "object"}}}},
                       **NOT_FOUND})
def network_tilejson(name: NetworkName, request: Request, session: SessionDep) -> JSONResponse:
    """TileJSON 3.0.0 of the network's vector tiles, with ``vector_layers``."""
    row = _one(session, name)
    return JSONResponse(tj.tilejson(_info(row), tiles_url(request, row)),
                        headers=NO_CACHE)


@router.get("/networks/{name}/style.json", response_model=None, dependencies=[only_query()],
            responses={200: {"content": {"application/json": {"schema": {"type": "object"}}}},
                       **NOT_FOUND})
def network_style(name: NetworkName, request: Request, session: SessionDep) -> JSONResponse:
    """A MapLibre style (version 8) drawing the network from its TileJSON."""
    row = _one(session, name)
    return JSONResponse(tj.style(_info(row), f"{network_url(request, row.name)}/tilejson.json"),
                        headers=NO_CACHE)


@router.get("/networks/{name}/tiles/metadata.json", response_model=None,
            dependencies=[only_query()],
            responses={200: {"content": {"application/json": {"schema": {"type": "object"}}}},
                       **NOT_FOUND})
def network_tiles_metadata(name: NetworkName, session: SessionDep) -> JSONResponse:
    """MBTiles-style metadata next to the tiles, for ``ogrinfo MVT:.../networks/{name}/tiles``.
    """
    row = _one(session, name)
    return JSONResponse(tj.mbtiles_metadata(_info(row), integer_ranges(session, row.id)),
                        headers=NO_CACHE)


@router.get("/networks/{name}/tiles/{z}/{x}/{y}.pbf", include_in_schema=False,
            dependencies=[only_query(VERSION_PARAM)])
def network_tile_pbf(name: NetworkName, z: str, x: str, y: str, session: SessionDep,
                     request: Request) -> Response:
    """The ``.mvt`` tile under the ``.pbf`` name GDAL's MVT driver asks for by default."""
    return network_tile(name, z, x, y, session, request)
