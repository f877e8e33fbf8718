"""HTTP routes: ``/tiles/{slug}/{z}/{x}/{y}[@2x].{png,jpg,webp}``, ``/layers``, TileJSON, and
an elevation layer's heights at points (``/layers/{slug}/elevation``).

Caching (:mod:`app.tiles.versioned`): the TileJSON's tile URLs carry the layer's version
token (``?v=``); a tile asked for with the current token is immutable for a year, any other
request gets ``max-age=60``. The strong ETag is that token (every ingest bumps the version; a
deleted and re-created layer gets a new one), so a client revalidates cheaply and gets 304
without any pixel being read, and the ETag changes as soon as the layer does.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Request, Response
from fastapi import Query as QueryParam
from fastapi.responses import FileResponse, RedirectResponse

from app import errors
from app.api.conditional import cache_headers, not_modified
from app.api.errors import responses
from app.api.query import only_query
from app.db.session import get_engine
from app.errors import InvalidParameterValueError, LayerNotFoundError, NotFoundError
from app.grid import parse_tile, tile_bounds
from app.params import LayerSlug, Shape, TileXY, TileZ
from app.routing.options import parse_points
from app.terrain.heights import heights_at
from app.tiles import catalog
from app.tiles.cache import tile_cache
from app.tiles.elevation import RENDERS, relief_renders
from app.tiles.encode import MEDIA_TYPES
from app.tiles.mosaic import compose_tile
from app.tiles.store import open_store
from app.tiles.versioned import VERSION_PARAM, versioned

# Raster layers are public; any request may still carry a malformed slug or find the
# database gone, and every layer-addressed one may name an unknown layer.
router = APIRouter(tags=["raster layers"], responses=responses(
    errors.InvalidParameterValueError, errors.DatabaseUnavailableError))
LAYER_ERRORS = responses(errors.LayerNotFoundError)
TILE_RE = re.compile(r"^(?P<y>[^@.]*)(?P<scale>@2x)?\.(?P<fmt>[A-Za-z0-9]+)$")
FORMATS = {"png": "png", "jpg": "jpg", "jpeg": "jpg", "webp": "webp"}
Format = Annotated[str, Shape(enum=sorted(FORMATS))]
TileName = Annotated[str, Shape(pattern=rf"^[0-9]{{1,8}}(@2x)?\.({'|'.join(FORMATS)})$",
                                description="{y}[@2x].{format}")]
SourceId = Annotated[str, Shape(pattern=r"^[0-9]{1,18}$")]
CACHE_CONTROL = "public, max-age=60"
#: Points one heights request may ask for (a dense route's waypoints fit; a grid does not).
MAX_HEIGHT_POINTS = 10_000
Render = Annotated[str | None, Shape(enum=list(RENDERS))]


def _format(name: str) -> str:
    """Our short format name for a requested one; the same 400 for a tile and a TileJSON."""
    fmt = FORMATS.get(name.lower())
    if fmt is None:
        raise InvalidParameterValueError(
            f"format must be one of {sorted(FORMATS)}, not {name[:20]!r}")
    return fmt


def _no_layer(slug: str) -> LayerNotFoundError:
    return LayerNotFoundError(f"no raster layer {slug[:100]!r}")


def _layer_json(layer: dict[str, Any], request: Request) -> dict[str, Any]:
    slug = layer["slug"]
    return {
        "slug": slug, "title": layer["title"], "kind": layer["kind"],
        "minzoom": layer["minzoom"], "maxzoom": layer["maxzoom"],
        "resolution_m": layer["resolution_m"], "bounds": layer["bounds"],
        "version": layer["version"], "source_count": layer["source_count"],
        "attribution": layer["attribution"],
        "updated_at": layer["updated_at"].isoformat(),
        "links": {
            "self": str(request.url_for("layer", slug=slug)),
            "tilejson": str(request.url_for("tilejson", slug=slug)),
            "tiles": versioned(_tile_template(request, slug, "png"), _token(layer)),
        },
        **({"renders": relief_renders(versioned(_tile_template(request, slug, "png"),
                                                _token(layer)))}
           if layer["kind"] == "elevation" else {}),
    }


def _token(layer: dict[str, Any]) -> str:
    return catalog.layer_token(layer["id"], layer["version"], layer["created_at"])


def _tile_template(request: Request, slug: str, fmt: str) -> str:
    base = str(request.base_url).rstrip("/")
    return f"{base}/tiles/{slug}/{{z}}/{{x}}/{{y}}.{fmt}"


@router.get("/layers")
def layers(request: Request) -> dict[str, Any]:
    """All raster layers."""
    with get_engine().connect() as conn:
        rows = catalog.list_layers(conn)
    return {"layers": [_layer_json(layer, request) for layer in rows]}


@router.get("/layers/{slug}", name="layer", responses=LAYER_ERRORS)
def layer(slug: LayerSlug, request: Request) -> dict[str, Any]:
    """One layer with its sources (paint order: last is on top)."""
    with get_engine().connect() as conn:
        found = catalog.get_layer(conn, slug)
    if found is None:
        raise _no_layer(slug)
    body = _layer_json(found, request)
    # Store paths are server internals: not part of the HTTP contract.
    body["sources"] = [
        {**{k: v for k, v in s.items() if k not in ("ingested_at", "uri")},
         "ingested_at": s["ingested_at"].isoformat(),
         "links": {"cog": str(request.url_for("source_cog", slug=slug,
                                              source_id=str(s["id"])))}}
        for s in found["sources"]]
    return body


@router.get("/layers/{slug}/sources/{source_id}.tif", name="source_cog", response_model=None,
            responses={200: {"content": {"image/tiff": {}}},
                       307: {"description": "Redirect to a presigned object-storage URL"},
                       **responses(errors.NotFoundError)})
def source_cog(slug: LayerSlug, source_id: SourceId) -> Response:
    """The source's COG exactly as stored: with HTTP ranges from a directory store (GDAL and
    QGIS read it in place over /vsicurl/), or a redirect to a presigned URL on S3."""
    if not source_id.isascii() or not source_id.isdigit():
        raise InvalidParameterValueError(f"source id {source_id[:20]!r} must be an integer")
    with get_engine().connect() as conn:
        uri = catalog.source_uri(conn, slug, int(source_id))
    if uri is None:
        raise NotFoundError(f"layer {slug[:100]!r} has no source {source_id}")
    store = open_store()
    url = store.presign(uri)
    if url is not None:
        return RedirectResponse(url, status_code=307)
    path = Path(store.resolve(uri))
    if not path.is_file():
        raise NotFoundError(f"the COG of source {source_id} is missing from the store")
    return FileResponse(path, media_type="image/tiff", filename=f"{slug}-{source_id}.tif",
                        headers={"Cache-Control": "no-cache"})


@router.get("/layers/{slug}/tilejson.json", name="tilejson", responses=LAYER_ERRORS,
            dependencies=[only_query("format")])
def tilejson(slug: LayerSlug, request: Request, response: Response,
             format: Format = "png") -> dict[str, Any]:
    """TileJSON 3.0.0 for the layer's XYZ tiles, whose URLs name the layer's current version
    (so they may be cached forever); the TileJSON itself is revalidated on every use."""
    fmt = _format(format)
    with get_engine().connect() as conn:
        found = catalog.layer_row(conn, slug)
    if found is None:
        raise _no_layer(slug)
    bounds = found["bounds"] or [-180.0, -85.0511, 180.0, 85.0511]
    center_zoom = max(found["minzoom"], min(found["maxzoom"], found["minzoom"] + 2))
    response.headers["Cache-Control"] = "no-cache"
    return {
        "tilejson": "3.0.0",
        "name": found["title"],
        "description": f"ugvmap raster layer {slug} ({found['kind']})",
        "version": f"1.0.{found['version']}",
        "attribution": found["attribution"] or "",
        "scheme": "xyz",
        "tiles": [versioned(_tile_template(request, slug, fmt), _token(found))],
        "minzoom": found["minzoom"],
        "maxzoom": found["maxzoom"],
        "bounds": bounds,
        "center": [(bounds[0] + bounds[2]) / 2, (bounds[1] + bounds[3]) / 2, center_zoom],
    }


@router.get("/layers/{slug}/elevation", responses=LAYER_ERRORS,
            dependencies=[only_query("points")])
def elevation(slug: LayerSlug,
              points: Annotated[str, QueryParam(description="lon,lat;lon,lat;...")]
              ) -> dict[str, Any]:
    """Heights of an elevation layer in metres at each point, in order (bilinear); ``null``
    where the layer has no data (outside it, or next to nodata)."""
    lonlats = parse_points(points, MAX_HEIGHT_POINTS)
    with get_engine().connect() as conn:
        heights = heights_at(conn, slug, lonlats)
    return {"layer": slug, "heights": [None if h is None else round(h, 3) for h in heights],
            "points": [list(p) for p in lonlats]}


@router.get("/tiles/{slug}/{z}/{x}/{tile}", response_model=None,
            dependencies=[only_query(VERSION_PARAM, "render")],
            responses={200: {"content": {t: {} for t in MEDIA_TYPES.values()}},
                       304: {"description": "Not modified: If-None-Match holds the ETag"},
                       **responses(errors.LayerNotFoundError, errors.TileOutOfRangeError,
                                          errors.RasterSourceMissingError)})
def tile(slug: LayerSlug, z: TileZ, x: TileXY, tile: TileName, request: Request,
         render: Render = None) -> Response:
    """One XYZ tile (256 px, or 512 px with ``@2x``) composed from all sources meeting it.
    An elevation layer is drawn as ``render``: hillshade (the default), slope (a colour ramp,
    its legend in ``GET /layers/{slug}``) or terrarium (heights for MapLibre's raster-dem)."""
    match = TILE_RE.match(tile)
    if not match:
        raise InvalidParameterValueError(
            "expected /tiles/{slug}/{z}/{x}/{y}[@2x].{format}")
    fmt = _format(match["fmt"])
    zi, xi, yi = parse_tile(z, x, match["y"])
    bbox = tile_bounds(zi, xi, yi)
    with get_engine().connect() as conn:
        query = catalog.tile_sources(conn, slug, bbox)
    if query is None:
        raise _no_layer(slug)
    headers = cache_headers(request, query.token, CACHE_CONTROL)
    unchanged = not_modified(request, headers)
    if unchanged is not None:
        return unchanged
    size = 512 if match["scale"] else 256
    key = (query.layer_id, query.version, zi, xi, yi, fmt, size, render)
    body = tile_cache().get(key)
    headers["X-Tile-Cache"] = "hit" if body is not None else "miss"
    if body is None:
        body = compose_tile(query, zi, xi, yi, fmt, size, render)
        tile_cache().put(key, body)
    return Response(body, media_type=MEDIA_TYPES[fmt], headers=headers)
