"""OGC API - Features, Part 1 (core + GeoJSON) over the road networks, readable by GDAL's
OAPIF driver and QGIS, with Part 3's queryables (as simple ``?name=value`` filters) and the
schemas clients need to type attributes right. Editing endpoints on the same items live in
``editing_router``; the landing page, conformance and API document in :mod:`app.api`.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from datetime import UTC, datetime
from typing import Any, Literal
from urllib.parse import urlencode

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy.orm import Session

from app import errors
from app.api.dependencies import SessionDep, read_access
from app.api.errors import responses
from app.errors import InvalidParameterValueError, NotFoundError
from app.lanes import lane
from app.network import collections as colls
from app.network import crs as crs_
from app.network import ogc_params, schemas

GEOJSON = "application/geo+json"
CRS84 = crs_.CRS84
GREGORIAN = "http://www.opengis.net/def/uom/ISO-8601/0/Gregorian"
OGC_REL = "http://www.opengis.net/def/rel/ogc/1.0/"
MAX_FID = 2**63 - 1
# Every read may need a token (UGVMAP_NETWORK_READ_ROLE) and may find the database gone.
READ_ERRORS = (errors.UnauthorizedError, errors.ForbiddenError,
               errors.DatabaseUnavailableError)

router = APIRouter(tags=["OGC API Features"], dependencies=[Depends(read_access)],
                   responses=responses(*READ_ERRORS))


class GeoJSONResponse(JSONResponse):
    """JSON served as ``application/geo+json``, as the GeoJSON conformance class requires,
    saying its CRS the way Part 2 clients (GDAL, QGIS) look for it."""

    media_type = GEOJSON

    def __init__(self, content: Any, status_code: int = 200,
                 headers: dict[str, str] | None = None, crs: crs_.Crs = crs_.DEFAULT,
                 **kw: Any) -> None:
        super().__init__(content, status_code, {"Content-Crs": crs.header, **(headers or {})},
                         **kw)


class SchemaResponse(JSONResponse):
    """A JSON Schema document, served as ``application/schema+json``."""

    media_type = schemas.SCHEMA_JSON


class Link(BaseModel):
    """A web link (RFC 8288) as OGC API documents carry them."""

    href: str
    rel: str
    type: str | None = None
    title: str | None = None


class CollectionInfo(BaseModel):
    """One collection as ``/collections`` describes it."""

    id: str
    title: str
    description: str
    itemType: Literal["feature"]  # noqa: N815 (the standard's member names)
    crs: list[str]
    storageCrs: str  # noqa: N815
    extent: dict[str, Any] | None = None
    links: list[Link]


class CollectionList(BaseModel):
    """The ``/collections`` document."""

    links: list[Link]
    collections: list[CollectionInfo]


def parse_fid(fid: str) -> int:
    """Feature ids are positive bigints; anything else simply does not exist (404)."""
    if not fid.isascii() or not fid.isdigit() or int(fid) > MAX_FID:
        raise NotFoundError(f"feature {fid[:100]!r} not found")
    return int(fid)


def link(href: str, rel: str, type_: str, title: str | None = None) -> dict[str, str]:
    """A link object; ``title`` only when there is one."""
    out = {"href": href, "rel": rel, "type": type_}
    if title:
        out["title"] = title
    return out


def base_url(request: Request) -> str:
    """The service's root URL as the client reached it, without the trailing slash."""
    return str(request.base_url).rstrip("/")


def _extent(extent: colls.Extent) -> dict[str, Any] | None:
    out: dict[str, Any] = {}
    if extent.bbox:
        out["spatial"] = {"bbox": [extent.bbox], "crs": CRS84}
    if extent.updated:
        out["temporal"] = {"interval": [[t.isoformat() for t in extent.updated]],
                           "trs": GREGORIAN}
    return out or None


def describe(request: Request, session: Session, c: colls.Collection) -> dict[str, Any]:
    """A collection's description: extent (space, and time for segments) and the links
    clients follow to its items, queryables and schemas."""
    base = f"{base_url(request)}/collections/{c.id}"
    extent = colls.extent(session, c)
    doc: dict[str, Any] = {
        "id": c.id,
        "title": f"{c.title or c.network} {c.kind}",
        "description": f"Road {c.kind} of network {c.network}",
        "itemType": "feature",
        "crs": crs_.advertised(extent.bbox),
        "storageCrs": CRS84,
        "links": [
            link(base, "self", "application/json"),
            link(f"{base}/items", "items", GEOJSON, f"{c.kind} of {c.network}"),
            link(f"{base}/feature-schema", "describedby", schemas.SCHEMA_JSON,
                 "JSON Schema of one GeoJSON item"),
            # The same link as GDAL before 3.8 matches it (case-sensitively).
            link(f"{base}/feature-schema", "describedBy", schemas.SCHEMA_JSON,
                 "JSON Schema of one GeoJSON item"),
            link(f"{base}/schema", f"{OGC_REL}schema", schemas.SCHEMA_JSON,
                 "Schema of the item properties"),
            link(f"{base}/queryables", f"{OGC_REL}queryables", schemas.SCHEMA_JSON,
                 "Properties the items can be filtered by"),
            link(f"{base}/queryables", "queryables", schemas.SCHEMA_JSON),
        ],
    }
    described = _extent(extent)
    if described:
        doc["extent"] = described
    return doc


@router.get("/collections", response_model=None,
            responses={200: {"model": CollectionList}})
def collections(request: Request, session: SessionDep) -> dict[str, Any]:
    """Every network's segment and node collections."""
    base = base_url(request)
    return {
        "links": [link(f"{base}/collections", "self", "application/json")],
        "collections": [describe(request, session, c)
                        for c in colls.list_collections(session)],
    }


NOT_FOUND = responses(errors.NotFoundError)


@router.get("/collections/{collection_id}", response_model=None,
            responses={200: {"model": CollectionInfo}, **NOT_FOUND})
def collection(collection_id: str, request: Request,
               session: SessionDep) -> dict[str, Any]:
    """One collection's description, with its extent and links."""
    return describe(request, session, colls.resolve(session, collection_id))


HEAVY_PAGE = 1_000
"""Pages of more features than this wait for a slot of the ``items`` lane (:mod:`app.lanes`):
40 clients reading 10,000-feature pages at once took 7.8 s each and every thread."""


async def page_lane(request: Request) -> AsyncIterator[None]:
    """Route dependency: hold a slot of the ``items`` lane while a large page is read (503
    ``ServiceBusy`` when its queue is full); smaller pages pass straight through."""
    limit, _ = ogc_params.paging(dict(request.query_params))
    if limit <= HEAVY_PAGE:
        yield
        return
    async with lane("items").slot():
        yield


ITEMS_DOC: dict[str, Any] = {"parameters": [ogc_params.parameter_ref(name)
                                            for name in ogc_params.ITEM_PARAMS]}


@router.get("/collections/{collection_id}/items", response_class=GeoJSONResponse,
            openapi_extra=ITEMS_DOC, dependencies=[Depends(page_lane)],
            responses={200: {"content": {GEOJSON: {"schema": {
                "$ref": "#/components/schemas/FeatureCollection"}}}},
                **responses(errors.InvalidParameterValueError, errors.NotFoundError,
                            errors.ServiceBusyError)})
def items(collection_id: str, request: Request,
          session: SessionDep) -> GeoJSONResponse:
    """A page of features, filtered by bbox, datetime and property values; unknown
    parameters are a 400 so a typo does not silently return everything."""
    c = colls.resolve(session, collection_id)
    query = dict(request.query_params)
    item_query = ogc_params.item_query(c.kind, query)
    crs = ogc_params.output_crs(query)
    limit, offset = ogc_params.paging(query)
    matched, features = colls.query_items(session, c, item_query, limit=limit, offset=offset,
                                          geometry=crs.output_sql())
    base = f"{base_url(request)}/collections/{c.id}/items"
    kept = {k: v for k, v in query.items() if k not in ("limit", "offset")}

    def page(rel: str, start: int) -> dict[str, str]:
        return link(f"{base}?{urlencode({**kept, 'limit': limit, 'offset': start})}",
                    rel, GEOJSON)

    links = [page("self", offset)]
    if offset + len(features) < matched:
        links.append(page("next", offset + limit))
    if offset > 0:
        links.append(page("prev", max(offset - limit, 0)))
    body = {"type": "FeatureCollection", "features": features, "numberMatched": matched,
            "numberReturned": len(features),
            "timeStamp": datetime.now(UTC).isoformat(timespec="seconds"), "links": links}
    return GeoJSONResponse(body, crs=crs)


def etag(version: int) -> str:
    """The strong ETag of a feature: its version, which every edit increments."""
    return f'"{version}"'


@router.get("/collections/{collection_id}/items/{fid}", response_class=GeoJSONResponse,
            openapi_extra={"parameters": [ogc_params.parameter_ref("crs"),
                                          ogc_params.parameter_ref("f")]},
            responses={200: {"content": {GEOJSON: {"schema": {
                "$ref": "#/components/schemas/Feature"}}}},
                **responses(errors.InvalidParameterValueError, errors.NotFoundError)})
def item(collection_id: str, fid: str, request: Request,
         session: SessionDep) -> GeoJSONResponse:
    """One feature, with its version as ETag for ``If-Match`` edits (``crs``: Part 2)."""
    c = colls.resolve(session, collection_id)
    query = dict(request.query_params)
    unknown = sorted(set(query) - {"crs", "f"})
    if unknown:
        raise InvalidParameterValueError(f"unknown query parameter {unknown[0][:100]!r}")
    if query.get("f", "json") not in ("json", "geojson"):
        raise InvalidParameterValueError("f must be json or geojson")
    crs = ogc_params.output_crs(query)
    feature = colls.get_item(session, c, parse_fid(fid), geometry=crs.output_sql())
    base = f"{base_url(request)}/collections/{c.id}"
    feature["links"] = [link(f"{base}/items/{feature['id']}", "self", GEOJSON),
                        link(base, "collection", "application/json")]
    return GeoJSONResponse(feature, headers={"ETag": etag(feature["properties"]["version"])},
                           crs=crs)


def _schema(session: Session, collection_id: str, request: Request,
            document: Callable[[colls.Kind, str, str], dict[str, Any]],
            title: str) -> SchemaResponse:
    """One of the collection's JSON Schema documents, its ``$id`` the URL asked for."""
    c = colls.resolve(session, collection_id)
    return SchemaResponse(document(c.kind, str(request.url.remove_query_params("f")),
                                   f"{title} {c.id}"))


SCHEMA_DOC = {200: {"content": {schemas.SCHEMA_JSON: {"schema": {"type": "object"}}}},
              **NOT_FOUND}


@router.get("/collections/{collection_id}/queryables", response_class=SchemaResponse,
            responses=SCHEMA_DOC)
def queryables(collection_id: str, request: Request, session: SessionDep) -> SchemaResponse:
    """The properties ``?name=value`` filters the items by (OGC API Features Part 3)."""
    return _schema(session, collection_id, request, schemas.queryables_document,
                   "Queryables of")


@router.get("/collections/{collection_id}/schema", response_class=SchemaResponse,
            responses=SCHEMA_DOC)
def schema(collection_id: str, request: Request, session: SessionDep) -> SchemaResponse:
    """Every property of the items with its type (OGC API Features Part 5, draft)."""
    return _schema(session, collection_id, request, schemas.part5_document, "Schema of")


@router.get("/collections/{collection_id}/feature-schema", response_class=SchemaResponse,
            responses=SCHEMA_DOC)
def feature_schema(collection_id: str, request: Request,
                   session: SessionDep) -> SchemaResponse:
    """JSON Schema of one GeoJSON item (the collection's ``describedby`` link)."""
    return _schema(session, collection_id, request, schemas.geojson_feature_document,
                   "A feature of")
