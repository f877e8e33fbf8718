"""HTTP side of editing: PATCH (JSON merge patch), DELETE, history, revert, and admin
split/merge.

Every write needs ``Authorization: Bearer`` with role editor (attributes, deleting a segment)
or admin (split and merge); reads are public unless ``UGVMAP_NETWORK_READ_ROLE`` is set.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse, Response
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from app import errors
from app.db.session import session_scope
from app.errors import (
    InvalidParameterValueError,
    MethodNotAllowedError,
    UnsupportedMediaTypeError,
)
from app.network import collections as colls
from app.network import editing, schemas, segment_deletion, topology_edits
from app.network.features import GEOJSON, READ_ERRORS, GeoJSONResponse, etag, parse_fid
from app.network.tokens import Principal, SessionDep, read_access, require_role
from app.params import Int

# Every write: token checks, unknown collection or feature, a nodes collection (405), a
# rule broken (422), a lost database.
WRITE_ERRORS = (errors.UnauthorizedError, errors.ForbiddenError, errors.NotFoundError,
                errors.MethodNotAllowedError, errors.InvalidValueError,
                errors.DatabaseUnavailableError)
router = APIRouter(tags=["Editing"])

EditorDep = Annotated[Principal, Depends(require_role("editor", "admin"))]
AdminDep = Annotated[Principal, Depends(require_role("admin"))]
PATCH_TYPES = ("application/merge-patch+json", "application/json")
Version = Annotated[int, Int("to", low=1, high=2**31 - 1)]


def _not_json(constant: str) -> Any:
    raise ValueError(f"{constant} is not a JSON number")


async def json_body(request: Request, accepted: tuple[str, ...] = PATCH_TYPES) -> Any:
    """The parsed JSON body, refused early when it has the wrong type (415) or is not JSON (400),
    so edit logic only sees a parsed value. ``NaN`` and ``Infinity``, which Python's parser
    takes but JSON (RFC 8259) does not have, are refused too. Size: the app's body limit
    stops an oversized body while it is read (413, :mod:`app.main`)."""
    content_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if content_type not in accepted:
        raise UnsupportedMediaTypeError(f"Content-Type must be one of: {', '.join(accepted)}")
    raw = await request.body()
    try:
        return json.loads(raw, parse_constant=_not_json)
    except (ValueError, RecursionError) as exc:
        raise InvalidParameterValueError(f"the body is not valid JSON ({exc})"[:200]) from None


def _segments(session: Session, collection_id: str) -> colls.Collection:
    c = colls.resolve(session, collection_id)
    if c.kind != "segments":
        raise MethodNotAllowedError("only segment collections are editable")
    return c


def feature_response(feature: dict[str, Any]) -> JSONResponse:
    """The edited feature with its new ETag, so the client can edit again without re-reading it."""
    return JSONResponse(feature, media_type=GEOJSON,
                        headers={"ETag": etag(feature["properties"]["version"])})


def _body_doc(schema: dict[str, Any], media_types: tuple[str, ...],
              *params: dict[str, Any]) -> dict[str, Any]:
    """API document of an edit: its JSON body, header/query parameters and bearer token."""
    return {"requestBody": {"required": True,
                            "content": {t: {"schema": schema} for t in media_types}},
            "parameters": list(params), "security": [{"bearer": []}]}


IF_MATCH = {"name": "If-Match", "in": "header", "required": True,
            "description": "The feature's ETag (its version), so edits cannot overwrite "
                           "each other", "schema": {"type": "string"}}
FEATURE_200: dict[int | str, dict[str, Any]] = {
    200: {"content": {GEOJSON: {"schema": {"$ref": "#/components/schemas/Feature"}}}}}
BODY_ERRORS = (errors.InvalidParameterValueError, errors.PayloadTooLargeError,
               errors.UnsupportedMediaTypeError)
PRECONDITIONS = (errors.PreconditionFailedError, errors.PreconditionRequiredError)


async def _in_session(work: Callable[[Session], dict[str, Any] | None]) -> Response:
    """Run blocking DB work in the thread pool, in one transaction; answer with its result
    (204 No Content when it has none: a deletion)."""

    def run() -> dict[str, Any] | None:
        with session_scope() as session:
            return work(session)

    result = await run_in_threadpool(run)
    if result is None:
        return Response(status_code=204)
    if result.get("type") == "Feature":
        return feature_response(result)
    return JSONResponse(result, media_type=GEOJSON)


@router.patch("/collections/{collection_id}/items/{fid}", response_class=GeoJSONResponse,
              openapi_extra=_body_doc(schemas.openapi_patch_body(), PATCH_TYPES, IF_MATCH),
              responses={**FEATURE_200, **errors.responses(*WRITE_ERRORS, *BODY_ERRORS,
                                                           *PRECONDITIONS)})
async def patch_item(collection_id: str, fid: str, request: Request,
                     principal: EditorDep) -> Response:
    """Edit a segment's attributes or geometry (editor; ``If-Match`` required)."""
    if_match = request.headers.get("if-match")
    body = await json_body(request)
    # Arguments run left to right: an unknown or read-only target (404/405) is said before
    # the precondition (428/412), which RFC 9110 evaluates only for a request that could
    # otherwise succeed.
    return await _in_session(lambda s: editing.patch_segment(
        s, _segments(s, collection_id), parse_fid(fid), editing.parse_if_match(if_match)[0],
        body, principal))


@router.delete("/collections/{collection_id}/items/{fid}", status_code=204,
               response_class=Response,
               openapi_extra={"security": [{"bearer": []}], "parameters": [IF_MATCH]},
               responses={204: {"description": "Deleted; its end nodes left without segments "
                                               "are deleted too"},
                          **errors.responses(errors.UnauthorizedError, errors.ForbiddenError,
                                             errors.NotFoundError,
                                             errors.MethodNotAllowedError,
                                             errors.DatabaseUnavailableError, *PRECONDITIONS)})
async def delete_item(collection_id: str, fid: str, request: Request,
                      principal: EditorDep) -> Response:
    """Delete a segment (editor; ``If-Match`` required): orphaned end nodes go with it, the
    others are re-kinded by degree, and the history keeps the whole segment."""
    if_match = request.headers.get("if-match")
    return await _in_session(lambda s: segment_deletion.delete_segment(
        s, _segments(s, collection_id), parse_fid(fid), editing.parse_if_match(if_match)[0],
        principal))


@router.get("/collections/{collection_id}/items/{fid}/history",
            dependencies=[Depends(read_access)],
            responses=errors.responses(*READ_ERRORS, errors.NotFoundError,
                                       errors.MethodNotAllowedError))
def item_history(collection_id: str, fid: str,
                 session: SessionDep) -> dict[str, Any]:
    """A segment's edit history."""
    c = _segments(session, collection_id)
    return {"id": parse_fid(fid), "edits": editing.history(session, c, parse_fid(fid))}


@router.post("/collections/{collection_id}/items/{fid}/revert", response_class=GeoJSONResponse,
             openapi_extra={"security": [{"bearer": []}], "parameters": [IF_MATCH]},
             responses={**FEATURE_200, **errors.responses(
                 *WRITE_ERRORS, errors.InvalidParameterValueError, *PRECONDITIONS)})
async def revert_item(collection_id: str, fid: str, to: Version, request: Request,
                      principal: EditorDep) -> Response:
    """Restore a segment to an earlier version, as a new version (editor; ``If-Match``
    required: reverting over an edit the client has not seen would silently undo it)."""
    if_match = request.headers.get("if-match")
    return await _in_session(lambda s: editing.revert_segment(
        s, _segments(s, collection_id), parse_fid(fid), to,
        editing.parse_if_match(if_match)[0], principal))


@router.post("/collections/{collection_id}/items/{fid}/split", response_class=GeoJSONResponse,
             openapi_extra=_body_doc(schemas.SPLIT_BODY, ("application/json",), IF_MATCH),
             responses={200: {"content": {GEOJSON: {"schema": {
                 "$ref": "#/components/schemas/FeatureCollection"}}}},
                 **errors.responses(*WRITE_ERRORS, *BODY_ERRORS, *PRECONDITIONS)})
async def split_item(collection_id: str, fid: str, request: Request,
                     principal: AdminDep) -> Response:
    """Split a segment at a fraction or point into two, adding a node (admin; ``If-Match``)."""
    if_match = request.headers.get("if-match")
    body = await json_body(request, ("application/json",))
    return await _in_session(lambda s: topology_edits.split_segment(
        s, _segments(s, collection_id), parse_fid(fid), editing.parse_if_match(if_match)[0],
        body, principal))


@router.post("/collections/{collection_id}/merge", response_class=GeoJSONResponse,
             openapi_extra=_body_doc(schemas.MERGE_BODY, ("application/json",), {
                 **IF_MATCH, "description": "Both segments' ETags, in the order of `segments`, "
                                            'e.g. `"3", "5"`'}),
             responses={**FEATURE_200, **errors.responses(*WRITE_ERRORS, *BODY_ERRORS,
                                                          *PRECONDITIONS)})
async def merge_items(collection_id: str, request: Request,
                      principal: AdminDep) -> Response:
    """Merge two segments that meet at a node only they share (admin; ``If-Match`` names both
    segments' ETags in the order of ``segments``, e.g. ``"3", "5"``)."""
    if_match = request.headers.get("if-match")
    body = await json_body(request, ("application/json",))
    return await _in_session(lambda s: topology_edits.merge_segments(
        s, _segments(s, collection_id), body, editing.parse_if_match(if_match, count=2),
        principal))
