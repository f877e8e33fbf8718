"""HTTP side of editing: PATCH (JSON merge patch), history, revert, and admin split/merge.

Every write needs ``Authorization: Bearer`` with role editor (attributes) or admin (topology
changes); reads are public unless ``UGVMAP_NETWORK_READ_ROLE`` is set.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from app.db.session import session_scope
from app.errors import (
    InvalidParameterValueError,
    MethodNotAllowedError,
    PayloadTooLargeError,
    UnsupportedMediaTypeError,
)
from app.network import collections as colls
from app.network import editing, topology_edits
from app.network.features import GEOJSON, etag, parse_fid
from app.network.tokens import Principal, SessionDep, read_access, require_role

router = APIRouter(tags=["Editing"])

EditorDep = Annotated[Principal, Depends(require_role("editor", "admin"))]
AdminDep = Annotated[Principal, Depends(require_role("admin"))]
PATCH_TYPES = ("application/merge-patch+json", "application/json")
MAX_BODY = 1_000_000


async def json_body(request: Request, accepted: tuple[str, ...] = PATCH_TYPES) -> Any:
    """The parsed JSON body, refused early when it has the wrong type (415), is too big (413) or is
    not JSON (400), so edit logic only sees a parsed value."""
    content_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if content_type not in accepted:
        raise UnsupportedMediaTypeError(f"Content-Type must be one of: {', '.join(accepted)}")
    raw = await request.body()
    if len(raw) > MAX_BODY:
        raise PayloadTooLargeError(f"the body must be under {MAX_BODY} bytes")
    try:
        return json.loads(raw)
    except (ValueError, RecursionError):
        raise InvalidParameterValueError("the body is not valid JSON") from None


def _segments(session: Session, collection_id: str) -> colls.Collection:
    c = colls.resolve(session, collection_id)
    if c.kind != "segments":
        raise MethodNotAllowedError("only segment collections are editable")
    return c


def feature_response(feature: dict[str, Any]) -> JSONResponse:
    """The edited feature with its new ETag, so the client can edit again without re-reading it."""
    return JSONResponse(feature, media_type=GEOJSON,
                        headers={"ETag": etag(feature["properties"]["version"])})


async def _in_session(work: Callable[[Session], dict[str, Any]]) -> JSONResponse:
    """Run blocking DB work in the thread pool, in one transaction; answer with its result."""

    def run() -> dict[str, Any]:
        with session_scope() as session:
            return work(session)

    result = await run_in_threadpool(run)
    if result.get("type") == "Feature":
        return feature_response(result)
    return JSONResponse(result, media_type=GEOJSON)


@router.patch("/collections/{collection_id}/items/{fid}")
async def patch_item(collection_id: str, fid: str, request: Request,
                     principal: EditorDep) -> JSONResponse:
    """Edit a segment's attributes or geometry (editor; ``If-Match`` required)."""
    expected = editing.parse_if_match(request.headers.get("if-match"))
    body = await json_body(request)
    return await _in_session(lambda s: editing.patch_segment(
        s, _segments(s, collection_id), parse_fid(fid), expected, body, principal))


@router.get("/collections/{collection_id}/items/{fid}/history",
            dependencies=[Depends(read_access)])
def item_history(collection_id: str, fid: str,
                 session: SessionDep) -> dict[str, Any]:
    """A segment's edit history."""
    c = _segments(session, collection_id)
    return {"id": parse_fid(fid), "edits": editing.history(session, c, parse_fid(fid))}


@router.post("/collections/{collection_id}/items/{fid}/revert")
async def revert_item(collection_id: str, fid: str, request: Request,
                      principal: EditorDep) -> JSONResponse:
    """Restore a segment to an earlier version, as a new version (editor; ``If-Match`` optional
    because the target is already named)."""
    to = request.query_params.get("to", "")
    if not to.isascii() or not to.isdigit() or len(to) > 9:
        raise InvalidParameterValueError("to must be a version number")
    if_match = request.headers.get("if-match")
    expected = editing.parse_if_match(if_match) if if_match else None
    return await _in_session(lambda s: editing.revert_segment(
        s, _segments(s, collection_id), parse_fid(fid), int(to), expected, principal))


@router.post("/collections/{collection_id}/items/{fid}/split")
async def split_item(collection_id: str, fid: str, request: Request,
                     principal: AdminDep) -> JSONResponse:
    """Split a segment at a fraction or point into two, adding a node (admin; ``If-Match``)."""
    expected = editing.parse_if_match(request.headers.get("if-match"))
    body = await json_body(request, ("application/json",))
    return await _in_session(lambda s: topology_edits.split_segment(
        s, _segments(s, collection_id), parse_fid(fid), expected, body, principal))


@router.post("/collections/{collection_id}/merge")
async def merge_items(collection_id: str, request: Request,
                      principal: AdminDep) -> JSONResponse:
    """Merge two segments that meet at a node only they share (admin)."""
    body = await json_body(request, ("application/json",))
    return await _in_session(lambda s: topology_edits.merge_segments(
        s, _segments(s, collection_id), body, principal))
