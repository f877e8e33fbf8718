"""HTTP side of editing: OGC API Features Part 4 on every collection (POST creates, PUT
replaces, PATCH merge-patches, DELETE deletes, OPTIONS says which), history and revert, and
the admin split/merge of segments.

Roles: editor or admin for attribute and geometry edits, creating and deleting segments;
admin for what splits or merges segments (``split``, ``merge``, and creating or deleting a
node, which do exactly that). Reads are public unless ``UGVMAP_NETWORK_READ_ROLE`` is set.
``If-Match`` follows ``UGVMAP_IF_MATCH`` (:mod:`app.network.editing`).

QGIS (3.32+) finds out what it may do with ``OPTIONS`` on the items and on one item, and looks
for ``POST``, ``PUT``, ``PATCH`` and ``DELETE`` in ``Allow``; it reads the new feature's id
from ``Location`` after ``/items/``. Both headers leave the server in that exact case
(:mod:`app.api.wire`), since QGIS 3.34 compares header names case-sensitively.
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
from app.api.dependencies import SessionDep, read_access, require_role
from app.api.errors import (
    MethodNotAllowedError,
    PayloadTooLargeError,
    UnsupportedMediaTypeError,
    allowed_methods,
    responses,
)
from app.db.session import retried
from app.errors import ForbiddenError, InvalidParameterValueError
from app.network import collections as colls
from app.network import crs as crs_
from app.network import (
    editing,
    lane_editing,
    node_editing,
    schemas,
    segment_deletion,
    segment_editing,
    topology_edits,
)
from app.network.features_router import (
    GEOJSON,
    READ_ERRORS,
    GeoJSONResponse,
    base_url,
    etag,
    parse_fid,
)
from app.network.tokens import Principal
from app.params import Int

# Every write: token checks, unknown collection or feature, a rule broken (422), a race lost
# even when tried again (409), a lost database.
WRITE_ERRORS = (errors.UnauthorizedError, errors.ForbiddenError, errors.NotFoundError,
                errors.InvalidValueError, errors.ConflictError,
                errors.DatabaseUnavailableError)
router = APIRouter(tags=["Editing"])

EditorDep = Annotated[Principal, Depends(require_role("editor", "admin"))]
AdminDep = Annotated[Principal, Depends(require_role("admin"))]
PATCH_TYPES = ("application/merge-patch+json", "application/json")
FEATURE_TYPES = (GEOJSON, "application/json")
ITEMS = "/collections/{collection_id}/items"
ITEM = ITEMS + "/{fid}"
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


def content_crs(request: Request) -> crs_.Crs:
    """The CRS of the body's coordinates (Part 2's ``Content-Crs``; CRS84 without one)."""
    return crs_.parse(request.headers.get("content-crs", crs_.CRS84), "Content-Crs")


def _segments(c: colls.Collection) -> colls.Collection:
    if c.kind != "segments":
        raise MethodNotAllowedError("only segment collections are split and merged")
    return c


def _admin_for_nodes(c: colls.Collection, principal: Principal) -> None:
    """Creating or deleting a node splits or merges segments: admin, as split and merge."""
    if c.kind == "nodes" and principal.role != "admin":
        raise ForbiddenError(f"role {principal.role!r} may not create or delete nodes (it "
                             "splits or merges segments); needs admin")


def feature_response(feature: dict[str, Any], status_code: int = 200,
                     location: str | None = None) -> JSONResponse:
    """The written feature with its new ETag, so the client can edit again without re-reading
    it (and, when created, where it lives)."""
    headers = {"ETag": etag(feature["properties"]["version"])}
    if location:
        headers["Location"] = location
    return GeoJSONResponse(feature, status_code=status_code, headers=headers)


def body_doc(schema: dict[str, Any], media_types: tuple[str, ...],
              *params: dict[str, Any]) -> dict[str, Any]:
    """API document of an edit: its JSON body, header/query parameters and bearer token."""
    return {"requestBody": {"required": True,
                            "content": {t: {"schema": schema} for t in media_types}},
            "parameters": list(params), "security": [{"bearer": []}]}


IF_MATCH = {"name": "If-Match", "in": "header", "required": False,
            "description": "The feature's ETag (its version): a stale one is refused (412), so "
                           "edits cannot overwrite each other. Without it the write applies "
                           "to the current version (recorded in the history) unless the "
                           "server requires it (`UGVMAP_IF_MATCH=required`: 428).",
            "schema": {"type": "string"}}
CONTENT_CRS = {"name": "Content-Crs", "in": "header", "required": False,
               "description": "CRS of the body's coordinates (OGC API Features Part 2), e.g. "
                              "`<http://www.opengis.net/def/crs/EPSG/0/3857>`; CRS84 without",
               "schema": {"type": "string"}}
FEATURE_200: dict[int | str, dict[str, Any]] = {
    200: {"content": {GEOJSON: {"schema": {"$ref": "#/components/schemas/Feature"}}}}}
BODY_ERRORS = (errors.InvalidParameterValueError, PayloadTooLargeError,
               UnsupportedMediaTypeError)
PRECONDITIONS = (errors.PreconditionFailedError, errors.PreconditionRequiredError)
SEGMENTS_ONLY = (MethodNotAllowedError,)


async def in_session(work: Callable[[Session], Any]) -> Any:
    """Run blocking DB work in the thread pool, in one transaction, tried again when it lost
    a deadlock or serialization failure (:func:`app.db.session.retried`: 409 if it keeps
    losing)."""
    return await run_in_threadpool(retried, work)


def _by_kind(c: colls.Collection, segments: Callable[..., Any], nodes: Callable[..., Any],
             lanes: Callable[..., Any] | None) -> Callable[..., Any]:
    """The writer of the collection's kind; a lane collection has no creating writer
    (:mod:`app.network.lane_editing`): 405."""
    if c.kind == "lanes":
        if lanes is None:
            raise MethodNotAllowedError("lane boundaries are made by `ugvmap ingest lanes`; "
                                        "edit or delete them (an `offset` one where paint "
                                        "is missing)")
        return lanes
    return segments if c.kind == "segments" else nodes


@router.options(ITEMS, include_in_schema=False, dependencies=[Depends(read_access)])
@router.options(ITEM, include_in_schema=False, dependencies=[Depends(read_access)])
def item_options(collection_id: str, request: Request, session: SessionDep) -> Response:
    """Part 4's ``OPTIONS``: the methods the items (or any one item, existing or not, as QGIS
    probes ``unknown_id`` on an empty collection) answer, in ``Allow``."""
    colls.resolve(session, collection_id)
    return Response(status_code=200, headers={"Allow": allowed_methods(request)})


@router.post(ITEMS, status_code=201, response_class=GeoJSONResponse,
             openapi_extra=body_doc({"$ref": "#/components/schemas/FeatureInput"}, FEATURE_TYPES,
                                     CONTENT_CRS),
             responses={201: {"description": "Created; `Location` is the new item",
                              "content": {GEOJSON: {"schema": {
                                  "$ref": "#/components/schemas/Feature"}}}},
                        **responses(*WRITE_ERRORS, *BODY_ERRORS, *SEGMENTS_ONLY)})
async def create_item(collection_id: str, request: Request, principal: EditorDep) -> Response:
    """Create a feature (Part 4): a segment is noded into the network at its ends (editor); a
    node splits the segment it lies on (admin); lane boundaries are not created here (405:
    ``ugvmap ingest lanes`` makes them)."""
    body = await json_body(request, FEATURE_TYPES)
    crs = content_crs(request)

    def create(session: Session) -> dict[str, Any]:
        c = colls.resolve(session, collection_id)
        _admin_for_nodes(c, principal)
        make = _by_kind(c, segment_editing.create_segment, node_editing.create_node, None)
        feature: dict[str, Any] = make(session, c, body, crs, principal)
        feature["links"] = [{"href": f"{base_url(request)}/collections/{c.id}/items/"
                                     f"{feature['id']}", "rel": "self", "type": GEOJSON}]
        return feature

    feature = await in_session(create)
    return feature_response(feature, 201, feature["links"][0]["href"])


@router.put(ITEM, response_class=GeoJSONResponse,
            openapi_extra=body_doc({"$ref": "#/components/schemas/FeatureInput"}, FEATURE_TYPES,
                                    IF_MATCH, CONTENT_CRS),
            responses={**FEATURE_200, **responses(*WRITE_ERRORS, *BODY_ERRORS,
                                                         *PRECONDITIONS)})
async def replace_item(collection_id: str, fid: str, request: Request,
                       principal: EditorDep) -> Response:
    """Replace a feature (Part 4): attributes not given take their defaults, server-kept
    properties are ignored; a segment's line keeps its nodes, a node's move drags its
    segments' ends (editor)."""
    body = await json_body(request, FEATURE_TYPES)
    return await _edit_item(request, collection_id, fid, body, principal,
                            segment_editing.replace_segment, node_editing.replace_node,
                            lane_editing.replace_lane)


@router.patch(ITEM, response_class=GeoJSONResponse,
              openapi_extra=body_doc(schemas.openapi_patch_body(), PATCH_TYPES, IF_MATCH,
                                      CONTENT_CRS),
              responses={**FEATURE_200, **responses(*WRITE_ERRORS, *BODY_ERRORS,
                                                           *PRECONDITIONS)})
async def patch_item(collection_id: str, fid: str, request: Request,
                     principal: EditorDep) -> Response:
    """Edit a feature's attributes or geometry with a JSON merge patch (editor)."""
    body = await json_body(request)
    return await _edit_item(request, collection_id, fid, body, principal,
                            segment_editing.patch_segment, node_editing.patch_node,
                            lane_editing.patch_lane)


async def _edit_item(request: Request, collection_id: str, fid: str, body: Any,
                     principal: Principal, segments: Callable[..., dict[str, Any]],
                     nodes: Callable[..., dict[str, Any]],
                     lanes: Callable[..., dict[str, Any]]) -> Response:
    """A PUT or PATCH of one feature with the writer of its kind. The collection and the
    feature id are resolved before the precondition (428/412), which RFC 9110 evaluates only
    for a request that could otherwise succeed."""
    if_match, crs = request.headers.get("if-match"), content_crs(request)

    def write(session: Session) -> dict[str, Any]:
        c = colls.resolve(session, collection_id)
        return _by_kind(c, segments, nodes, lanes)(session, c, parse_fid(fid),
                                            editing.expected_version(if_match), body, crs,
                                            principal)

    return feature_response(await in_session(write))


@router.delete(ITEM, status_code=204, response_class=Response,
               openapi_extra={"security": [{"bearer": []}], "parameters": [IF_MATCH]},
               responses={204: {"description": "Deleted; a segment's end nodes left without "
                                               "segments go too, a node's two segments are "
                                               "merged"},
                          **responses(*WRITE_ERRORS, *PRECONDITIONS)})
async def delete_item(collection_id: str, fid: str, request: Request,
                      principal: EditorDep) -> Response:
    """Delete a segment (editor: orphaned end nodes go with it, the others are re-kinded by
    degree, the history keeps the whole segment) or a node between two segments (admin:
    they are merged)."""
    if_match = request.headers.get("if-match")

    def delete(session: Session) -> None:
        c = colls.resolve(session, collection_id)
        _admin_for_nodes(c, principal)
        remove = _by_kind(c, segment_deletion.delete_segment, node_editing.delete_node,
                          lane_editing.delete_lane)
        remove(session, c, parse_fid(fid), editing.expected_version(if_match), principal)

    await in_session(delete)
    return Response(status_code=204)


@router.get(ITEM + "/history", dependencies=[Depends(read_access)],
            responses={200: {"content": {"application/json": {"schema": schemas.HISTORY}}},
                       **responses(*READ_ERRORS, errors.NotFoundError)})
def item_history(collection_id: str, fid: str, session: SessionDep) -> Response:
    """A feature's edit history, oldest first (``conditional: false``: written without
    ``If-Match``, over whatever version was current); the edits' JSON as PostgreSQL wrote
    it (:func:`app.network.editing.history`)."""
    c = colls.resolve(session, collection_id)
    feature_id = parse_fid(fid)
    edits = editing.history(session, c, feature_id)
    return Response(f'{{"id": {feature_id}, "edits": {edits}}}', media_type="application/json")


@router.post(ITEM + "/revert", response_class=GeoJSONResponse,
             openapi_extra={"security": [{"bearer": []}], "parameters": [IF_MATCH]},
             responses={**FEATURE_200, **responses(
                 *WRITE_ERRORS, errors.InvalidParameterValueError, *PRECONDITIONS)})
async def revert_item(collection_id: str, fid: str, to: Version, request: Request,
                      principal: EditorDep) -> Response:
    """Restore a feature to an earlier version, as a new version (editor; a stale
    ``If-Match`` is refused: reverting over an edit the client has not seen would undo it)."""
    if_match = request.headers.get("if-match")

    def revert(session: Session) -> dict[str, Any]:
        c = colls.resolve(session, collection_id)
        return editing.revert_feature(session, c, parse_fid(fid), to,
                                      editing.expected_version(if_match), principal)

    return feature_response(await in_session(revert))


@router.post(ITEM + "/split", response_class=GeoJSONResponse,
             openapi_extra=body_doc(schemas.SPLIT_BODY, ("application/json",), IF_MATCH),
             responses={200: {"content": {GEOJSON: {"schema": schemas.SPLIT_ANSWER}}},
                 **responses(*WRITE_ERRORS, *SEGMENTS_ONLY, *BODY_ERRORS,
                                    *PRECONDITIONS)})
async def split_item(collection_id: str, fid: str, request: Request,
                     principal: AdminDep) -> Response:
    """Split a segment at a fraction or point into two, adding a node (admin)."""
    if_match = request.headers.get("if-match")
    body = await json_body(request, ("application/json",))

    def split(session: Session) -> dict[str, Any]:
        c = _segments(colls.resolve(session, collection_id))
        return topology_edits.split_segment(session, c, parse_fid(fid),
                                            editing.expected_version(if_match), body,
                                            principal)

    return GeoJSONResponse(await in_session(split))


@router.post("/collections/{collection_id}/merge", response_class=GeoJSONResponse,
             openapi_extra=body_doc(schemas.MERGE_BODY, ("application/json",), {
                 **IF_MATCH, "description": "Both segments' ETags, in the order of `segments`, "
                                            'e.g. `"3", "5"`'}),
             responses={**FEATURE_200, **responses(*WRITE_ERRORS, *SEGMENTS_ONLY,
                                                          *BODY_ERRORS, *PRECONDITIONS)})
async def merge_items(collection_id: str, request: Request,
                      principal: AdminDep) -> Response:
    """Merge two segments that meet at a node only they share (admin; ``If-Match`` names both
    segments' ETags in the order of ``segments``, e.g. ``"3", "5"``)."""
    if_match = request.headers.get("if-match")
    body = await json_body(request, ("application/json",))

    def merge(session: Session) -> dict[str, Any]:
        c = _segments(colls.resolve(session, collection_id))
        return topology_edits.merge_segments(session, c, body,
                                             editing.parse_if_match(if_match, count=2),
                                             principal)

    return feature_response(await in_session(merge))
