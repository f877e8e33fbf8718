"""``/layers/{slug}/labels``: a layer's labels over HTTP (read as layers are: public; written
by editors and admins), for the web map's Teach tool and any client.

``POST`` takes a GeoJSON Feature or FeatureCollection whose features carry ``label``
(``road`` or ``not_road``) and stores all of them or none; ``DELETE`` removes one label or,
on the collection, all of them.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response
from sqlalchemy.orm import Session

from app import errors
from app.api.dependencies import SessionDep, require_role
from app.api.errors import PayloadTooLargeError, UnsupportedMediaTypeError, responses
from app.api.query import only_query
from app.labels import store
from app.network.editing_router import FEATURE_TYPES, body_doc, in_session, json_body
from app.network.features_router import GEOJSON, GeoJSONResponse
from app.network.tokens import Principal
from app.params import Int, LayerSlug

# No label URL takes a query parameter: a typo (``?label=road`` on a DELETE of all) is a 400,
# never silently ignored.
router = APIRouter(tags=["raster layers"], dependencies=[only_query()], responses=responses(
    errors.InvalidParameterValueError, errors.LayerNotFoundError,
    errors.DatabaseUnavailableError))
EditorDep = Annotated[Principal, Depends(require_role("editor", "admin"))]
LabelId = Annotated[int, Int("label id", low=1, high=2**63 - 1)]
LABELS = "/layers/{slug}/labels"
WRITE_ERRORS = responses(errors.UnauthorizedError, errors.ForbiddenError)
LABEL_SCHEMA: dict[str, Any] = {
    "type": "object", "required": ["type", "geometry", "properties"],
    "properties": {
        "type": {"type": "string", "enum": ["Feature"]},
        "geometry": {"type": "object", "description": "LineString (road or not_road) or "
                                                      "Polygon (not_road), lon/lat"},
        "properties": {"type": "object", "required": ["label"], "properties": {
            "label": {"type": "string", "enum": ["road", "not_road"]}}}}}
LABELS_BODY = {"oneOf": [LABEL_SCHEMA, {
    "type": "object", "required": ["type", "features"],
    "properties": {"type": {"type": "string", "enum": ["FeatureCollection"]},
                   "features": {"type": "array", "items": LABEL_SCHEMA, "minItems": 1,
                                "maxItems": store.MAX_PER_REQUEST}}}]}
STORED_LABEL: dict[str, Any] = {
    "type": "object", "required": ["type", "id", "geometry", "properties"],
    "properties": {
        "type": {"type": "string", "enum": ["Feature"]},
        "id": {"type": "integer"},
        "geometry": {"type": "object", "description": "LineString or Polygon, lon/lat"},
        "properties": {"type": "object", "required": ["label", "created_by", "created_at"],
                       "properties": {
                           "label": {"type": "string", "enum": ["road", "not_road"]},
                           "created_by": {"type": "string"},
                           "created_at": {"type": "string", "format": "date-time"}}}}}
COLLECTION_200: dict[int | str, dict[str, Any]] = {200: {"content": {GEOJSON: {"schema": {
    "type": "object", "required": ["type", "features", "numberReturned"],
    "properties": {"type": {"type": "string", "enum": ["FeatureCollection"]},
                   "features": {"type": "array", "items": STORED_LABEL},
                   "numberReturned": {"type": "integer"}}}}}}}


def _collection(features: list[dict[str, Any]]) -> dict[str, Any]:
    return {"type": "FeatureCollection", "features": features,
            "numberReturned": len(features)}


@router.get(LABELS, response_class=GeoJSONResponse, responses=COLLECTION_200)
def labels(slug: LayerSlug, session: SessionDep) -> GeoJSONResponse:
    """The layer's labels, oldest first: ``label`` (road / not_road), who drew it and when."""
    return GeoJSONResponse(_collection(store.list_labels(session.connection(), slug)))


@router.post(LABELS, status_code=201, response_class=GeoJSONResponse,
             openapi_extra=body_doc(LABELS_BODY, FEATURE_TYPES),
             responses={201: {"description": "Stored: the new labels with their ids",
                              **COLLECTION_200[200]},
                        **WRITE_ERRORS,
                        **responses(errors.InvalidValueError, PayloadTooLargeError,
                                    UnsupportedMediaTypeError)})
async def add_labels(slug: LayerSlug, request: Request, principal: EditorDep) -> Response:
    """Add labels (editor): all of them or, when any is refused (not on the layer's imagery,
    wrong geometry for its label, invalid, over the limits), none (422 naming each)."""
    body = await json_body(request, FEATURE_TYPES)

    def add(session: Session) -> list[dict[str, Any]]:
        store.layer_id(session.connection(), slug)  # an unknown layer is a 404 before all
        return store.add_labels(session, slug, store.parse_labels(body), principal.name)

    return GeoJSONResponse(_collection(await in_session(add)), status_code=201)


@router.delete(LABELS + "/{label_id}", status_code=204, response_class=Response,
               openapi_extra={"security": [{"bearer": []}]},
               responses={204: {"description": "Deleted"}, **WRITE_ERRORS,
                          **responses(errors.NotFoundError)})
async def delete_label(slug: LayerSlug, label_id: LabelId, principal: EditorDep) -> Response:
    """Delete one label (editor)."""
    await in_session(lambda session: store.delete_label(session, slug, label_id))
    return Response(status_code=204)


@router.delete(LABELS, openapi_extra={"security": [{"bearer": []}]}, responses=WRITE_ERRORS)
async def clear_labels(slug: LayerSlug, principal: EditorDep) -> dict[str, int]:
    """Delete all of the layer's labels (editor); how many there were."""
    return {"deleted": await in_session(lambda session: store.clear_labels(session, slug))}
