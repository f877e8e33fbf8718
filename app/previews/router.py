"""``/layers/{slug}/previews``: re-extract the view on the map with the layer's labels (a job
for the workers), read the result, and accept it into a network.

Asking and accepting need an editor token (a preview costs seconds of a worker; accepting
edits a network); reading a preview is public, as layers are.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse

from app import errors
from app.api.dependencies import SessionDep, require_role
from app.api.errors import PayloadTooLargeError, UnsupportedMediaTypeError, responses
from app.network.editing_router import body_doc, in_session, json_body
from app.network.tokens import Principal
from app.params import Int, LayerSlug
from app.previews import store
from app.previews.accept import accept_preview

router = APIRouter(tags=["raster layers"], responses=responses(
    errors.InvalidParameterValueError, errors.LayerNotFoundError,
    errors.DatabaseUnavailableError))
EditorDep = Annotated[Principal, Depends(require_role("editor", "admin"))]
PreviewId = Annotated[int, Int("preview id", low=1, high=2**63 - 1)]
PREVIEWS = "/layers/{slug}/previews"
WRITE_ERRORS = responses(errors.UnauthorizedError, errors.ForbiddenError,
                         errors.InvalidValueError, PayloadTooLargeError,
                         UnsupportedMediaTypeError)
JSON = ("application/json",)
BBOX_BODY = {"type": "object", "required": ["bbox"], "properties": {"bbox": {
    "type": "array", "items": {"type": "number"}, "minItems": 4, "maxItems": 4,
    "description": "the view: minlon, minlat, maxlon, maxlat"}}}
ACCEPT_BODY = {"type": "object", "required": ["network"],
               "properties": {"network": {"type": "string"}}}


@router.post(PREVIEWS, status_code=202, openapi_extra=body_doc(BBOX_BODY, JSON),
             responses={202: {"description": "Queued: the preview's id; `Location` is where "
                                             "to read it"}, **WRITE_ERRORS})
async def request_preview(slug: LayerSlug, request: Request,
                          principal: EditorDep) -> JSONResponse:
    """Extract the roads of a view of the layer (at most 2048 x 2048 px of its finest
    resolution) with its labels as the sample, zero-shot without labels."""
    bbox = store.parse_bbox(await json_body(request, JSON))
    preview_id = await in_session(lambda s: store.request_preview(s, slug, bbox))
    return JSONResponse({"id": preview_id, "status": "queued"}, status_code=202,
                        headers={"Location": f"{PREVIEWS.format(slug=slug)}/{preview_id}"})


@router.get(PREVIEWS + "/{preview_id}", responses=responses(errors.NotFoundError))
def read_preview(slug: LayerSlug, preview_id: PreviewId, session: SessionDep
                 ) -> dict[str, Any]:
    """The preview's status and progress and, once it succeeded, its roads (GeoJSON lines
    with their confidence), the layer version they were made from, the labels used and the
    seconds taken; a failed one's error."""
    return store.read_preview(session, slug, preview_id)


@router.post(PREVIEWS + "/{preview_id}/accept", openapi_extra=body_doc(ACCEPT_BODY, JSON),
             responses={**WRITE_ERRORS, **responses(errors.NotFoundError,
                                                    errors.ConflictError)})
async def accept(slug: LayerSlug, preview_id: PreviewId, request: Request,
                 principal: EditorDep) -> dict[str, int]:
    """Put the preview's roads into a network (``{"network": NAME}``): its unreviewed
    extracted segments in the view are replaced, segments a person made or edited kept; 409
    when the layer changed since the preview."""
    body = await json_body(request, JSON)
    if not isinstance(body, dict) or set(body) != {"network"}:
        raise errors.InvalidValueError('the body must be {"network": NAME}',
                                       errors={"body": "must have only 'network'"})
    result: dict[str, int] = await in_session(
        lambda s: accept_preview(s, slug, preview_id, body["network"], principal))
    return result
