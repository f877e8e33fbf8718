"""Change sets: ``/networks/{name}/changes`` lists those re-surveys proposed for a network,
``/change-sets/{id}`` reads one (public unless ``UGVMAP_NETWORK_READ_ROLE`` is set, as
the network is); an editor accepts or rejects its
proposals one by one (``changes``), by box (``bbox``), by kind (``kind``) or all (``all``),
and reverts a whole change set in one step.

Why a path of their own for one set (as ``/jobs/{id}``): a set's id is unique across
networks, and under ``/networks/{name}/`` a five-part path is OSRM's
(``{service}/{version}/{profile}``), which would also answer ``.../changes/1/accept``."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request

from app import errors
from app.api.dependencies import SessionDep, read_access, require_role
from app.api.errors import PayloadTooLargeError, UnsupportedMediaTypeError, responses
from app.network.editing_router import body_doc, in_session, json_body
from app.network.resurvey import changes
from app.network.tokens import Principal
from app.params import Int, NetworkName

router = APIRouter(tags=["road network"], responses=responses(
    errors.InvalidParameterValueError, errors.NotFoundError, errors.DatabaseUnavailableError))
EditorDep = Annotated[Principal, Depends(require_role("editor", "admin"))]
SetId = Annotated[int, Int("change set id", low=1, high=2**63 - 1)]
CHANGES = "/networks/{name}/changes"
SET = "/change-sets/{set_id}"
JSON = ("application/json",)
WRITE_ERRORS = responses(errors.UnauthorizedError, errors.ForbiddenError,
                         errors.InvalidValueError, errors.ConflictError, PayloadTooLargeError,
                         UnsupportedMediaTypeError)
SELECTION_BODY = {"type": "object", "description": (
    "which proposals: `changes` (ids, one by one: also those on segments a person edited), "
    "`bbox` (minlon, minlat, maxlon, maxlat), `kind` (moved, new, missing) or `all`: true; "
    "`bbox` and `kind` may be combined. Bulk choices leave out proposals on segments a person "
    "edited."), "properties": {
    "changes": {"type": "array", "items": {"type": "integer"}, "maxItems": 10000},
    "bbox": {"type": "array", "items": {"type": "number"}, "minItems": 4, "maxItems": 4},
    "kind": {"type": "string", "enum": list(changes.KINDS)},
    "all": {"type": "boolean"}}}


def selection(body: Any) -> changes.Selection:
    """The body's choice of proposals, or a 422 saying what is wrong with it."""
    def bad(why: str) -> errors.InvalidValueError:
        return errors.InvalidValueError(f"the body {why}", errors={"body": why})

    if not isinstance(body, dict) or not body:
        raise bad('must be an object: {"changes": [ids]}, {"bbox": [..]}, {"kind": K} or '
                  '{"all": true}')
    unknown = sorted(set(body) - {"changes", "bbox", "kind", "all"})
    if unknown:
        raise bad(f"has unknown keys: {', '.join(k[:40] for k in unknown)}")
    if "all" in body and (body["all"] is not True or len(body) > 1):
        raise bad('takes "all": true alone')
    ids = body.get("changes", [])
    if "changes" in body and (len(body) > 1 or not isinstance(ids, list) or not ids
                              or not all(type(i) is int and i > 0 for i in ids)):
        raise bad('takes "changes" alone, a non-empty list of change ids')
    kind = body.get("kind")
    if kind is not None and kind not in changes.KINDS:
        raise bad(f"kind must be one of {', '.join(changes.KINDS)}")
    box = body.get("bbox")
    if box is not None:
        if not (isinstance(box, list) and len(box) == 4
                and all(type(v) in (int, float) for v in box)
                and -180 <= box[0] < box[2] <= 180 and -90 <= box[1] < box[3] <= 90):
            raise bad("bbox must be [minlon, minlat, maxlon, maxlat] in degrees")
        box = tuple(float(v) for v in box)
    return changes.Selection(tuple(ids), box, kind)


@router.get(CHANGES, dependencies=[Depends(read_access)])
def list_change_sets(name: NetworkName, session: SessionDep) -> list[dict[str, Any]]:
    """The network's change sets, oldest first: source, status, counts per outcome, and per
    kind and status how many proposals there are."""
    return changes.change_sets(session, name)


@router.get(SET, dependencies=[Depends(read_access)])
def read_change_set(set_id: SetId, session: SessionDep) -> dict[str, Any]:
    """One change set (its network, source, status, counts) and its proposals (GeoJSON: the
    proposed line of a moved or new road, the line of a missing one; kind, status, segment,
    whether a person edited it)."""
    return changes.change_set(session, changes.network_of(session, set_id), set_id)


@router.post(SET + "/accept", openapi_extra=body_doc(SELECTION_BODY, JSON),
             responses=WRITE_ERRORS)
async def accept(set_id: SetId, request: Request, principal: EditorDep) -> dict[str, int]:
    """Accept proposals: each becomes an edit of the network (history action ``resurvey``
    naming the change set), seen by routing at once. Counts accepted, edited (left for a look
    one by one), stale (the segment changed since) and refused."""
    chosen = selection(await json_body(request, JSON))
    result: dict[str, int] = await in_session(
        lambda s: changes.accept(s, changes.network_of(s, set_id), set_id, chosen,
                                 principal))
    return result


@router.post(SET + "/reject", openapi_extra=body_doc(SELECTION_BODY, JSON),
             responses=WRITE_ERRORS)
async def reject(set_id: SetId, request: Request, principal: EditorDep) -> dict[str, int]:
    """Reject proposals: the network is not changed."""
    chosen = selection(await json_body(request, JSON))
    result: dict[str, int] = await in_session(
        lambda s: changes.reject(s, changes.network_of(s, set_id), set_id, chosen,
                                 principal))
    return result


@router.post(SET + "/revert", openapi_extra={"security": [{"bearer": []}]},
             responses=WRITE_ERRORS)
async def revert(set_id: SetId, principal: EditorDep) -> dict[str, int]:
    """Undo every accepted change of the set (newest first, history action
    ``resurvey-revert``) and close it."""
    result: dict[str, int] = await in_session(
        lambda s: changes.revert(s, changes.network_of(s, set_id), set_id, principal))
    return result
