"""The OGC API landing page and conformance declaration.

``/`` serves two audiences: a browser gets the web map, an OGC client (QGIS and GDAL ask with
``Accept: application/json``; ``?f=json`` works too) gets the landing page, whose links lead to
the API document, the conformance classes and the collections. ``/ogc`` is the landing page
whatever the client accepts: the stable URL to give QGIS.
"""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, JSONResponse, RedirectResponse
from pydantic import BaseModel

from app import errors
from app.api.errors import responses
from app.errors import InvalidParameterValueError
from app.network import crs
from app.network.features_router import Link, base_url, link
from app.web.router import index_page

OPENAPI_30 = "application/vnd.oai.openapi+json;version=3.0"
JSON = "application/json"
HTML = "text/html"
FEATURES = "http://www.opengis.net/spec/ogcapi-features-1/1.0/conf/"
FEATURES_3 = "http://www.opengis.net/spec/ogcapi-features-3/1.0/conf/"
FEATURES_4 = "http://www.opengis.net/spec/ogcapi-features-4/1.0/conf/"
CONFORMANCE = [
    FEATURES + "core",
    FEATURES + "geojson",
    FEATURES + "oas30",
    FEATURES_3 + "queryables",
    FEATURES_3 + "queryables-query-parameters",
    # Part 2: crs / bbox-crs / Content-Crs (QGIS offers a collection's CRS list only then).
    crs.CONFORMANCE,
    # Part 4 (draft 20-002r1): POST/PUT/DELETE, PATCH, on GeoJSON features, with strong ETags
    # and If-Match. (The draft's table spells the ETag class under /req/; its other classes
    # and every other OGC API use /conf/, as here.) QGIS decides from OPTIONS, not from these.
    FEATURES_4 + "create-replace-delete",
    FEATURES_4 + "update",
    FEATURES_4 + "features",
    FEATURES_4 + "optimistic-locking-etags",
    # Part 5 is a draft; QGIS reads the schema (and so types every attribute right) only
    # when this class is declared.
    "http://www.opengis.net/spec/ogcapi-features-5/1.0/conf/schemas",
]

router = APIRouter(tags=["OGC API"])


class LandingPage(BaseModel):
    """The landing page document."""

    title: str
    description: str
    links: list[Link]


class Conformance(BaseModel):
    """The conformance declaration."""

    conformsTo: list[str]  # noqa: N815 (the standard's member name)


def landing_document(request: Request) -> dict[str, Any]:
    """The landing page: what the service is and where its parts are."""
    base = base_url(request)
    return {
        "title": request.app.title,
        "description": request.app.description,
        "links": [
            link(str(request.url), "self", JSON, "This document"),
            link(f"{base}/", "alternate", HTML, "The web map"),
            link(f"{base}/openapi.json", "service-desc", OPENAPI_30,
                 "The API definition (OpenAPI 3.0)"),
            link(f"{base}/docs", "service-doc", HTML, "The API documentation"),
            link(f"{base}/conformance", "conformance", JSON, "Conformance classes"),
            link(f"{base}/collections", "data", JSON, "Road network collections"),
            link(f"{base}/networks", "related", JSON,
                 "Road networks as vector tiles (TileJSON, MapLibre styles)"),
            link(f"{base}/layers", "related", JSON, "Raster layers (TileJSON)"),
        ],
    }


def _quality(accept: str, media_type: str) -> float:
    """The q-value ``accept`` gives ``media_type`` (exact, ``type/*`` or ``*/*``), 0 if none."""
    major = media_type.split("/")[0]
    best, specificity = 0.0, -1
    for part in accept.split(","):
        name, *params = (p.strip() for p in part.split(";"))
        rank = {media_type: 2, f"{major}/*": 1, "*/*": 0}.get(name.lower(), -1)
        if rank > specificity:
            q = 1.0
            for param in params:
                key, _, value = param.partition("=")
                if key.strip() == "q":
                    try:
                        q = float(value)
                    except ValueError:
                        q = 0.0
            best, specificity = q, rank
    return best


def wants_json(request: Request) -> bool:
    """JSON for ``?f=json`` or an Accept header preferring JSON to HTML; HTML on a tie, so a
    browser (or ``*/*``) gets the map."""
    f = request.query_params.get("f")
    if f is not None:
        if f not in ("json", "html"):
            raise InvalidParameterValueError("f must be json or html")
        return f == "json"
    accept = request.headers.get("accept", "*/*")
    return _quality(accept, JSON) > _quality(accept, HTML)


@router.get("/", response_model=None, responses={
    200: {"description": "The landing page (JSON) or the web map (HTML)",
          "content": {JSON: {"schema": {"$ref": "#/components/schemas/LandingPage"}},
                      HTML: {"schema": {"type": "string"}}}},
    **responses(errors.InvalidParameterValueError)},
    openapi_extra={"parameters": [{"name": "f", "in": "query", "required": False,
                                   "schema": {"type": "string", "enum": ["json", "html"]}}]})
def root(request: Request) -> JSONResponse | FileResponse:
    """The web map for browsers, the OGC API landing page for JSON clients."""
    vary = {"Vary": "Accept"}
    if wants_json(request):
        return JSONResponse(landing_document(request), headers=vary)
    page = index_page()
    page.headers.update(vary)
    return page


@router.get("/ogc", response_model=None, responses={200: {"model": LandingPage}})
def ogc_landing(request: Request) -> dict[str, Any]:
    """The OGC API landing page, whatever the client accepts (the URL to give QGIS)."""
    return landing_document(request)


@router.get("/ogc/{path:path}", include_in_schema=False)
def under_ogc(path: str, request: Request) -> RedirectResponse:
    """Clients given ``/ogc`` as their root (GDAL appends ``/collections``) find the API."""
    query = f"?{request.url.query}" if request.url.query else ""
    return RedirectResponse(f"{base_url(request)}/{path}{query}", status_code=308)


@router.get("/conformance", response_model=None, responses={200: {"model": Conformance}})
def conformance() -> dict[str, list[str]]:
    """The conformance classes the service implements."""
    return {"conformsTo": CONFORMANCE}
