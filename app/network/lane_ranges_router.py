"""``/collections/{network}-segments/items/{id}/lanes``: a segment's lane ranges, read by
anyone who may read the network and replaced whole by an editor as a new version of the
segment (:mod:`app.network.lane_ranges` says why)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse
from sqlalchemy.orm import Session

from app import errors
from app.api.dependencies import SessionDep, read_access
from app.api.errors import MethodNotAllowedError, responses
from app.network import collections as colls
from app.network import editing, lane_ranges
from app.network.editing_router import (
    BODY_ERRORS,
    IF_MATCH,
    ITEM,
    PRECONDITIONS,
    WRITE_ERRORS,
    EditorDep,
    body_doc,
    in_session,
    json_body,
)
from app.network.features_router import READ_ERRORS, etag, parse_fid

router = APIRouter(tags=["Editing"])
LANES = ITEM + "/lanes"
RANGE = {"type": "object", "required": ["station_from_m", "station_to_m", "lanes_forward",
                                        "lanes_backward", "widths_m"],
         "properties": {
             "station_from_m": {"type": "number", "description": "metres from the start"},
             "station_to_m": {"type": "number"},
             "lanes_forward": {"type": "integer", "minimum": 0},
             "lanes_backward": {"type": "integer", "minimum": 0},
             "widths_m": {"type": "array", "items": {"type": "number"},
                          "description": "each lane's width, right to left along the segment"},
             "offsets_m": {"type": "array", "items": {"type": "number"},
                           "description": "each boundary's offset right to left, + left of "
                                          "the segment; left out: the line between the "
                                          "directions on the segment"},
             "confidence": {"type": ["number", "null"], "readOnly": True},
             "source": {"type": "string", "enum": ["paint", "offset", "edited"],
                        "readOnly": True}}}
ANSWER = {"type": "object", "properties": {
    "segment_id": {"type": "integer"}, "version": {"type": "integer"},
    "length_m": {"type": "number"}, "ranges": {"type": "array", "items": RANGE}}}


def _segments(session: Session, collection_id: str) -> colls.Collection:
    c = colls.resolve(session, collection_id)
    if c.kind != "segments":
        raise MethodNotAllowedError("lane ranges belong to segments: "
                                    "/collections/{network}-segments/items/{id}/lanes")
    return c


def _answer(session: Session, feature: dict[str, Any]) -> JSONResponse:
    props = feature["properties"]
    return JSONResponse({"segment_id": feature["id"], "version": props["version"],
                         "length_m": props["length_m"],
                         "ranges": lane_ranges.read_ranges(session, feature["id"])},
                        headers={"ETag": etag(props["version"])})


@router.get(LANES, dependencies=[Depends(read_access)],
            responses={200: {"content": {"application/json": {"schema": ANSWER}}},
                       **responses(*READ_ERRORS, errors.NotFoundError, MethodNotAllowedError)})
def segment_lanes(collection_id: str, fid: str, session: SessionDep) -> JSONResponse:
    """A segment's lane ranges in station order (empty when it has none), with the segment's
    version as the ETag to send back in ``If-Match``."""
    c = _segments(session, collection_id)
    return _answer(session, colls.get_item(session, c, parse_fid(fid)))


@router.put(LANES,
            openapi_extra=body_doc({"type": "object", "required": ["ranges"], "properties": {
                "ranges": {"type": "array", "items": RANGE}}}, ("application/json",),
                IF_MATCH),
            responses={200: {"content": {"application/json": {"schema": ANSWER}}},
                       **responses(*WRITE_ERRORS, *BODY_ERRORS, *PRECONDITIONS,
                                   MethodNotAllowedError)})
async def put_segment_lanes(collection_id: str, fid: str, request: Request,
                            principal: EditorDep) -> JSONResponse:
    """Replace a segment's lane ranges (editor): one new version of the segment, its lane
    counts those of the longest range, the old ranges in its history (revertable);
    ``ugvmap ingest lanes`` keeps them from then on. An empty list removes them."""
    body = await json_body(request, ("application/json",))
    if_match = request.headers.get("if-match")

    def put(session: Session) -> JSONResponse:
        c = _segments(session, collection_id)
        expected = editing.expected_version(if_match)
        feature = editing.lock_feature(session, c, parse_fid(fid), expected)
        props = feature["properties"]
        ranges = lane_ranges.check_ranges(body, props["length_m"], props["oneway"])
        written = editing.write_change(session, c, feature,
                                       {lane_ranges.KEY: ranges, **lane_ranges.counts_of(ranges)},
                                       principal, "lanes", conditional=expected is not None)
        return _answer(session, written)

    answer: JSONResponse = await in_session(put)
    return answer
