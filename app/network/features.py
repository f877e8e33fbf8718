"""OGC API - Features, Part 1 (core + GeoJSON) over the road networks, readable by GDAL's
OAPIF driver and QGIS. Editing endpoints on the same items live in ``editing_router``.
"""

from __future__ import annotations

import math
from typing import Any
from urllib.parse import urlencode

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse
from sqlalchemy.orm import Session

from app.errors import InvalidParameterValueError, NotFoundError
from app.network import collections as colls
from app.network.tokens import SessionDep, read_access

router = APIRouter(tags=["OGC API Features"], dependencies=[Depends(read_access)])

GEOJSON = "application/geo+json"
CRS84 = "http://www.opengis.net/def/crs/OGC/1.3/CRS84"
CONFORMANCE = [
    "http://www.opengis.net/spec/ogcapi-features-1/1.0/conf/core",
    "http://www.opengis.net/spec/ogcapi-features-1/1.0/conf/geojson",
    "http://www.opengis.net/spec/ogcapi-features-1/1.0/conf/oas30",
]
DEFAULT_LIMIT = 10
MAX_LIMIT = 10_000
ITEM_PARAMS = {"bbox", "limit", "offset", "f", "bbox-crs"}
MAX_FID = 2**63 - 1


def parse_fid(fid: str) -> int:
    """Feature ids are positive bigints; anything else simply does not exist (404)."""
    if not fid.isascii() or not fid.isdigit() or int(fid) > MAX_FID:
        raise NotFoundError(f"feature {fid[:100]!r} not found")
    return int(fid)


def _int_param(name: str, value: str | None, default: int, low: int) -> int:
    if value is None:
        return default
    try:
        number = int(value)
    except ValueError:
        raise InvalidParameterValueError(f"{name} must be an integer") from None
    if number < low:
        raise InvalidParameterValueError(f"{name} must be >= {low}")
    return number


def parse_bbox(value: str | None) -> list[float] | None:
    """``minlon,minlat,maxlon,maxlat`` as four finite numbers, or None; anything else is a 400
    rather than a query that silently matches nothing."""
    if value is None:
        return None
    try:
        box = [float(v) for v in value.split(",")]
    except ValueError:
        raise InvalidParameterValueError(
            "bbox must be four numbers: minlon,minlat,maxlon,maxlat") from None
    if len(box) != 4 or not all(math.isfinite(v) for v in box):
        raise InvalidParameterValueError(
            "bbox must be four finite numbers: minlon,minlat,maxlon,maxlat")
    if box[0] > box[2] or box[1] > box[3]:
        raise InvalidParameterValueError(
            "bbox min must not exceed max (antimeridian boxes not supported)")
    return box


def _link(href: str, rel: str, type_: str, title: str | None = None) -> dict[str, str]:
    link = {"href": href, "rel": rel, "type": type_}
    if title:
        link["title"] = title
    return link


def _base(request: Request) -> str:
    return str(request.base_url).rstrip("/")


def _describe(request: Request, session: Session, c: colls.Collection) -> dict[str, Any]:
    base = f"{_base(request)}/collections/{c.id}"
    box = colls.extent(session, c)
    doc: dict[str, Any] = {
        "id": c.id,
        "title": f"{c.title or c.network} {c.kind}",
        "description": f"Road {c.kind} of network {c.network}",
        "itemType": "feature",
        "crs": [CRS84],
        "links": [_link(base, "self", "application/json"),
                  _link(f"{base}/items", "items", GEOJSON, f"{c.kind} of {c.network}")],
    }
    if box:
        doc["extent"] = {"spatial": {"bbox": [box], "crs": CRS84}}
    return doc


@router.get("/conformance")
def conformance() -> dict[str, list[str]]:
    """The OGC API conformance classes we implement."""
    return {"conformsTo": CONFORMANCE}


@router.get("/collections")
def collections(request: Request, session: SessionDep) -> dict[str, Any]:
    """Every network's segment and node collections."""
    base = _base(request)
    return {
        "links": [_link(f"{base}/collections", "self", "application/json")],
        "collections": [_describe(request, session, c)
                        for c in colls.list_collections(session)],
    }


@router.get("/collections/{collection_id}")
def collection(collection_id: str, request: Request,
               session: SessionDep) -> dict[str, Any]:
    """One collection's description, with its extent and links."""
    return _describe(request, session, colls.resolve(session, collection_id))


@router.get("/collections/{collection_id}/items")
def items(collection_id: str, request: Request,
          session: SessionDep) -> JSONResponse:
    """A page of features, filtered by bbox; unknown parameters are a 400 so a typo does not
    silently return everything."""
    query = request.query_params
    unknown = sorted(set(query.keys()) - ITEM_PARAMS)
    if unknown:
        raise InvalidParameterValueError(f"unknown query parameter {unknown[0][:100]!r}")
    if query.get("bbox-crs", CRS84) != CRS84:
        raise InvalidParameterValueError(f"bbox-crs must be {CRS84}")
    c = colls.resolve(session, collection_id)
    limit = min(_int_param("limit", query.get("limit"), DEFAULT_LIMIT, 1), MAX_LIMIT)
    offset = _int_param("offset", query.get("offset"), 0, 0)
    if offset > MAX_FID:
        raise InvalidParameterValueError("offset is too large")
    bbox = parse_bbox(query.get("bbox"))
    matched, features = colls.query_items(session, c, bbox=bbox, limit=limit, offset=offset)
    base = f"{_base(request)}/collections/{c.id}/items"
    kept = {k: v for k, v in query.items() if k in ("bbox", "bbox-crs")}

    def page(rel: str, start: int) -> dict[str, str]:
        return _link(f"{base}?{urlencode({**kept, 'limit': limit, 'offset': start})}",
                     rel, GEOJSON)

    links = [page("self", offset)]
    if offset + len(features) < matched:
        links.append(page("next", offset + limit))
    if offset > 0:
        links.append(page("prev", max(offset - limit, 0)))
    body = {"type": "FeatureCollection", "features": features, "numberMatched": matched,
            "numberReturned": len(features), "links": links}
    return JSONResponse(body, media_type=GEOJSON)


def etag(version: int) -> str:
    """The strong ETag of a feature: its version, which every edit increments."""
    return f'"{version}"'


@router.get("/collections/{collection_id}/items/{fid}")
def item(collection_id: str, fid: str, request: Request,
         session: SessionDep) -> JSONResponse:
    """One feature; segments carry their version as ETag for ``If-Match`` edits."""
    c = colls.resolve(session, collection_id)
    feature = colls.get_item(session, c, parse_fid(fid))
    base = f"{_base(request)}/collections/{c.id}"
    feature["links"] = [_link(f"{base}/items/{feature['id']}", "self", GEOJSON),
                        _link(base, "collection", "application/json")]
    headers = {}
    if c.kind == "segments":
        headers["ETag"] = etag(feature["properties"]["version"])
    return JSONResponse(feature, media_type=GEOJSON, headers=headers)
