"""The API document (``/openapi.json``, OpenAPI 3.0) and its browsable form (``/docs``).

FastAPI describes the routes; :mod:`app.api.openapi30` turns that into 3.0; this module adds
what only the running service knows or what FastAPI cannot infer:

- the items parameters (``limit`` with its maximum, ``bbox``, ``datetime``, ...) as shared
  ``components/parameters``, and the bearer-token security scheme;
- our error body wherever FastAPI would claim its own ``{"detail"}`` shape;
- one literal ``/collections/{id}/items`` path per collection, typed by its kind and listing
  its ``?name=value`` filters: QGIS and GDAL look the collection's own path up to find the
  page-size maximum and which filters the server runs, and schemathesis checks real items
  against the typed schemas.
"""

from __future__ import annotations

import copy
from typing import Any

from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse, JSONResponse

from app.api.dependencies import SessionDep, check_read_role
from app.api.landing import OPENAPI_30
from app.api.openapi30 import document_30
from app.errors import UgvmapError
from app.network import collections as colls
from app.network import ogc_params, properties, schemas
from app.network.features_router import GEOJSON

router = APIRouter(include_in_schema=False)
ITEMS = "/collections/{collection_id}/items"
KIND_SCHEMA: dict[colls.Kind, str] = {"segments": "Segment", "nodes": "Node",
                                     "lanes": "LaneBoundary"}
SECURITY = {"bearer": {"type": "http", "scheme": "bearer",
                       "description": "A token from `ugvmap tokens create --role ...` (also "
                                      "accepted as the password of HTTP Basic, any user name: "
                                      "what QGIS sends from a connection's credentials)"}}


def _replace_refs(node: Any, old: str, new: str) -> Any:
    if isinstance(node, dict):
        if node.get("$ref") == old:
            return {**node, "$ref": new}
        return {k: _replace_refs(v, old, new) for k, v in node.items()}
    if isinstance(node, list):
        return [_replace_refs(v, old, new) for v in node]
    return node


def _errors_as_json(doc: dict[str, Any]) -> None:
    """FastAPI files an error model under the route's own media type (GeoJSON, JSON Schema);
    error bodies are always ``application/json``."""
    for item in doc["paths"].values():
        for op in item.values():
            for status, response in op.get("responses", {}).items():
                content = response.get("content", {})
                if status[0] in "45" and len(content) == 1:
                    (body,) = content.values()
                    if body.get("schema", {}).get("$ref", "").endswith("/ErrorBody"):
                        response["content"] = {"application/json": body}


def static_document(app: FastAPI) -> dict[str, Any]:
    """Everything that does not depend on the data, built once per app."""
    cached: dict[str, Any] | None = getattr(app.state, "openapi_30", None)
    if cached is not None:
        return cached
    doc = document_30(get_openapi(title=app.title, version=app.version,
                                  description=app.description, routes=app.routes))
    # Request validation answers with our error body (422 InvalidValue), not FastAPI's.
    doc = _replace_refs(doc, "#/components/schemas/HTTPValidationError",
                        "#/components/schemas/ErrorBody")
    _errors_as_json(doc)
    found = doc["components"]["schemas"]
    for unused in ("HTTPValidationError", "ValidationError"):
        found.pop(unused, None)
    found["Feature"] = schemas.openapi_feature(None)
    found["FeatureInput"] = schemas.openapi_feature_input()
    found["FeatureCollection"] = schemas.openapi_feature_collection("Feature")
    for kind, name in KIND_SCHEMA.items():
        found[f"{name}Feature"] = schemas.openapi_feature(kind)
        found[f"{name}FeatureCollection"] = schemas.openapi_feature_collection(f"{name}Feature")
    doc["components"]["parameters"] = copy.deepcopy(ogc_params.PARAMETERS)
    doc["components"]["securitySchemes"] = SECURITY
    app.state.openapi_30 = doc
    return doc


def _literal(operation: dict[str, Any], collection: colls.Collection, *,
             extra: list[dict[str, Any]], schema: str | None = None) -> dict[str, Any]:
    """A templated items operation made literal for one collection (its page typed as
    ``schema``, when given)."""
    op = copy.deepcopy(operation)
    op["parameters"] = [p for p in op.get("parameters", [])
                        if p.get("name") != "collection_id"] + extra
    op["operationId"] = f"{op['operationId']}_{collection.id}"
    op["summary"] = f"{op.get('summary', '')}: {collection.id}"
    if schema:
        op["responses"]["200"]["content"] = {
            GEOJSON: {"schema": {"$ref": f"#/components/schemas/{schema}"}}}
    return op


def with_collections(doc: dict[str, Any], found: list[colls.Collection]) -> dict[str, Any]:
    """The document plus a literal items path for each collection (reading and, OGC API
    Features Part 4, creating: the methods its ``OPTIONS`` lists)."""
    paths = dict(doc["paths"])
    for c in found:
        name = KIND_SCHEMA[c.kind]
        filters = [ogc_params.filter_parameter(p) for p in properties.queryables(c.kind)]
        paths[f"/collections/{c.id}/items"] = {
            "get": _literal(doc["paths"][ITEMS]["get"], c, extra=filters,
                            schema=f"{name}FeatureCollection"),
            "post": _literal(doc["paths"][ITEMS]["post"], c, extra=[])}
    return {**doc, "paths": paths}


@router.get("/openapi.json")
def openapi_document(request: Request, session: SessionDep) -> JSONResponse:
    """The API document, with the collections the caller may read."""
    try:
        check_read_role(request, session)
        found = colls.list_collections(session)
    except UgvmapError:  # reads need a token this caller lacks: no collection names
        found = []
    doc = with_collections(static_document(request.app), found)
    return JSONResponse(doc, media_type=OPENAPI_30)


@router.get("/docs")
def docs() -> HTMLResponse:
    """Swagger UI on the API document."""
    return get_swagger_ui_html(openapi_url="/openapi.json", title="ugvmap API")
