"""Change sets in the database: propose what a re-survey changes in a network, and accept,
reject or revert those proposals (migration ``0013_change_sets``).

Why proposals live apart from ``road_segments``: routing, tiles and exports read the network
as people accepted it; a proposal becomes part of it only when accepted, and then as the
editing API's own edit (a new version of a moved segment, a created or a deleted segment),
with a history row (action ``resurvey``) naming the change set and the change. So routing
sees only accepted changes, history and versions work as for any edit, and a whole change
set is undone by editing back (action ``resurvey-revert``).

A segment a person created or edited (a history row with an action other than the machine's
own: an accepted preview, an accepted or reverted re-survey change) is never changed without
a look at it alone: its proposals carry ``edited`` and are left out of every bulk accept (by
box, by kind, all); so is a new road that joins such a segment (joining its side splits it).
An accept never applies a proposal to a segment edited since it was made (its version
changed): that one is reported ``stale`` and stays proposed.

Two updates of one network at once: the second is refused at once (409 ``Conflict``), not
queued behind the first, since it would propose against a network the first is about to
change the proposals of.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np
import shapely
from shapely.geometry import shape
from shapely.geometry.base import BaseGeometry
from sqlalchemy import text
from sqlalchemy.orm import Session

from app.errors import ConflictError, InvalidValueError, NotFoundError, PreconditionFailedError
from app.network import collections as colls
from app.network import crs as crs_
from app.network.editing import lock_feature, lock_topology, write_change
from app.network.resurvey.frame import LocalFrame
from app.network.resurvey.matching import OldSegment, Tolerances, match
from app.network.segment_deletion import delete_segment
from app.network.segment_editing import create_segment
from app.network.tokens import Principal
from app.network.topology_edits import merge_segments

ACCEPTED = "resurvey"
"""History action of an accepted change."""
PREVIEW_ACCEPTED = "accept"
"""History action of a change accepted with a road preview (:mod:`app.previews.accept`)."""
REVERTED = "resurvey-revert"
"""History action of an accepted change undone by reverting its change set."""
LANES_FROM_PAINT = "lanes-from-paint"
"""History action of a segment's lane counts set from its painted lanes (``ingest lanes``)."""
MACHINE_ACTIONS = (PREVIEW_ACCEPTED, ACCEPTED, REVERTED, LANES_FROM_PAINT)
"""History actions that are not a person's edit (an accepted preview is the model's work;
an accepted change is the re-survey's line; lane counts read from the paint)."""
KINDS = ("moved", "new", "missing")
Kind = Literal["moved", "new", "missing"]


@dataclass(frozen=True)
class SurveyLine:
    """One line of the re-survey: lon/lat coordinates and the attributes a new road gets
    (the editable segment properties, plus ``confidence`` of an extraction)."""

    coords: list[tuple[float, float]]
    attributes: dict[str, Any]


@dataclass(frozen=True)
class Selection:
    """Which proposals of a change set an accept or reject takes: given ids, those meeting a
    lon/lat box, those of one kind, or all (kind and box may be combined)."""

    ids: tuple[int, ...] = ()
    bbox: tuple[float, float, float, float] | None = None
    kind: Kind | None = None

    @property
    def bulk(self) -> bool:
        """Not one by one: proposals on segments a person edited are left out."""
        return not self.ids


def network(session: Session, name: str) -> colls.Collection:
    """The network's segment collection; 404 if there is none of that name."""
    row = colls.network_row(session, name)
    if row is None:
        raise NotFoundError(f"no network {name[:100]!r} (see `ugvmap network list`)")
    return colls.Collection(name, row.id, "segments", row.title)


def network_of(session: Session, set_id: int) -> str:
    """The name of the network change set ``set_id`` belongs to; 404 if there is none."""
    name: str | None = session.execute(text(
        "SELECT n.name FROM change_sets c JOIN networks n ON n.id = c.network_id "
        "WHERE c.id = :id"), {"id": set_id}).scalar()
    if name is None:
        raise NotFoundError(f"no change set {set_id} (see GET /networks/NAME/changes)")
    return name


SEGMENTS = (
    "SELECT s.id, ST_AsGeoJSON(s.geom, 9)::json->'coordinates' AS coords, s.version, "
    "  EXISTS (SELECT 1 FROM segment_edits e WHERE e.network_id = s.network_id "
    "    AND e.segment_id = s.id AND e.action <> ALL(:machine)) AS edited "
    "FROM road_segments s WHERE s.network_id = :n ORDER BY s.id")


def _lock_update(session: Session, c: colls.Collection) -> None:
    """Refuse a second update of the network while one runs (held to the transaction's end)."""
    free: bool = session.execute(text(
        "SELECT pg_try_advisory_xact_lock(hashtext('ugvmap.resurvey'), :n)"),
        {"n": c.network_id}).scalar_one()
    if not free:
        raise ConflictError(f"another update of network {c.network!r} is running; wait for it "
                            "to finish and review its change set (`ugvmap network changes "
                            f"{c.network}`)")


def propose(session: Session, name: str, lines: Sequence[SurveyLine], *, source: str,
            coverage: BaseGeometry | None, principal: Principal,
            tol: Tolerances | None = None, layer: tuple[int, int] | None = None,
            elsewhere: bool = False) -> dict[str, Any]:
    """Match ``lines`` against network ``name`` and store what they change as a new change
    set (in the caller's transaction): its id, source and counts. ``coverage`` (lon/lat) is
    where the new data could show roads (a layer's footprints); None: the lines' own area.
    ``layer``: (id, version) of the layer the lines were extracted from. ``elsewhere``: lines
    of a place where the network has no road yet are taken (a preview of a new area), not
    refused as a survey of another place."""
    tol = tol or Tolerances()
    if not lines:
        raise InvalidValueError(f"{source}: no road lines to match")
    c = network(session, name)
    _lock_update(session, c)
    rows = session.execute(text(SEGMENTS), {"n": c.network_id,
                                            "machine": list(MACHINE_ACTIONS)}).all()
    frame = LocalFrame.around([line.coords for line in lines])
    new = [frame.metres(line.coords) for line in lines]
    if coverage is None:
        coverage_m = shapely.MultiPoint(np.concatenate(new)).convex_hull.buffer(tol.match_m)
    else:
        coverage_m = shapely.transform(coverage, frame.metres)
    old = [OldSegment(r.id, frame.metres(r.coords), r.edited) for r in rows]
    if old and not elsewhere and not any(coverage_m.intersects(shapely.linestrings(s.coords))
                                         for s in old):
        raise InvalidValueError(f"{source} does not overlap network {name!r}: nothing of it "
                                "could be matched (update a network with data of its own area)",
                                errors={"source": "does not overlap the network"})
    result = match(old, new, coverage_m, tol)
    versions = {r.id: r.version for r in rows}
    outline = (None if coverage is None
               else shapely.to_wkt(shapely.set_precision(coverage, 1e-9)))
    set_id: int = session.execute(text(
        "INSERT INTO change_sets (network_id, source, layer_id, layer_version, coverage, "
        "tolerances, counts, created_by) VALUES (:n, :source, :layer, :lv, "
        "ST_GeomFromText(:coverage, 4326), CAST(:tol AS jsonb), CAST(:counts AS jsonb), :who) "
        "RETURNING id"),
        {"n": c.network_id, "source": source, "layer": layer[0] if layer else None,
         "lv": layer[1] if layer else None, "coverage": outline, "tol": json.dumps(asdict(tol)),
         "counts": json.dumps(result.counts()), "who": principal.name}).scalar_one()
    geometry = {r.id: r.coords for r in rows}
    proposals: list[dict[str, Any]] = []
    for m in result.moved:
        proposals.append({"kind": "moved", "sid": m.segment_id, "edited": m.edited,
                          "coords": frame.lonlat(m.coords), "attributes": None,
                          "detail": {"offset_m": m.offset_m, "seen_share": m.seen_share}})
    for gone in result.missing:
        proposals.append({"kind": "missing", "sid": gone.segment_id, "edited": gone.edited,
                          "coords": geometry[gone.segment_id], "attributes": None,
                          "detail": {"seen_share": gone.seen_share}})
    edited = {r.id for r in rows if r.edited}
    for road in result.new:
        # Joining a road's side splits it: a person's road is then changed too.
        proposals.append({"kind": "new", "sid": None,
                          "edited": bool(edited & set(road.joins)),
                          "coords": frame.lonlat(road.coords),
                          "attributes": lines[road.line].attributes,
                          "detail": {"joins": list(road.joins)}})
    if proposals:
        session.execute(text(
            "INSERT INTO proposed_changes (change_set_id, kind, segment_id, segment_version, "
            "edited, geom, attributes, detail) VALUES (:set, :kind, :sid, :version, :edited, "
            "ST_SetSRID(ST_GeomFromGeoJSON(:geometry), 4326), CAST(:attributes AS jsonb), "
            "CAST(:detail AS jsonb))"),
            [{"set": set_id, "kind": p["kind"], "sid": p["sid"],
              "version": versions.get(p["sid"]) if p["sid"] else None, "edited": p["edited"],
              "geometry": json.dumps({"type": "LineString", "coordinates": p["coords"]}),
              "attributes": None if p["attributes"] is None else json.dumps(p["attributes"]),
              "detail": json.dumps(p["detail"])} for p in proposals])
    return {"id": set_id, "network": name, "source": source, "counts": result.counts()}


def _change_set(session: Session, c: colls.Collection, set_id: int, *,
                open_only: bool = False) -> Any:
    row = session.execute(text(
        "SELECT id, status FROM change_sets WHERE id = :id AND network_id = :n FOR UPDATE"),
        {"id": set_id, "n": c.network_id}).first()
    if row is None:
        raise NotFoundError(f"network {c.network!r} has no change set {set_id}")
    if open_only and row.status != "open":
        raise ConflictError(f"change set {set_id} was reverted; its changes cannot be "
                            "accepted any more")
    return row


def _selected(session: Session, set_id: int, selection: Selection, status: str) -> list[Any]:
    where = ["change_set_id = :set", "status = :status"]
    params: dict[str, Any] = {"set": set_id, "status": status}
    if selection.ids:
        where.append("id = ANY(:ids)")
        params["ids"] = list(selection.ids)
    if selection.kind:
        where.append("kind = :kind")
        params["kind"] = selection.kind
    if selection.bbox:
        where.append("ST_Intersects(geom, ST_MakeEnvelope(:x0, :y0, :x1, :y1, 4326))")
        params.update(zip(("x0", "y0", "x1", "y1"), selection.bbox, strict=True))
    # Moves first, then deletions, then new roads: a new road joins the network as it will be.
    return list(session.execute(text(
        "SELECT id, kind, segment_id, segment_version, edited, attributes, "
        "ST_AsGeoJSON(geom, 9)::json AS geometry FROM proposed_changes "
        f"WHERE {' AND '.join(where)} "
        "ORDER BY array_position(ARRAY['moved', 'missing', 'new'], kind), id"), params).all())


def _apply(session: Session, c: colls.Collection, change: Any, note: dict[str, Any],
           principal: Principal, action: str) -> int | None:
    """Apply one proposal as the editing API would; the segment a new road became."""
    if change.kind == "moved":
        feature = lock_feature(session, c, change.segment_id, change.segment_version)
        write_change(session, c, feature, {"geometry": change.geometry}, principal, action,
                     note=note)
        return None
    if change.kind == "missing":
        delete_segment(session, c, change.segment_id, change.segment_version, principal,
                       action=action, note=note)
        return None
    properties = dict(change.attributes or {})
    confidence = properties.pop("confidence", None)
    created = create_segment(session, c, {"type": "Feature", "geometry": change.geometry,
                                          "properties": properties},
                             crs_.DEFAULT, principal, action=action, note=note,
                             confidence=confidence)
    return int(created["id"])


def accept(session: Session, name: str, set_id: int, selection: Selection,
           principal: Principal, *, action: str = ACCEPTED,
           note: dict[str, Any] | None = None) -> dict[str, int]:
    """Accept the selected proposals (in the caller's transaction): counts ``accepted``,
    ``edited`` (left for a one-by-one look: a person's segment), ``stale`` (the segment
    changed or went since the proposal) and ``refused`` (a new road the network cannot take:
    it duplicates a road or joins one node twice). ``action`` and ``note``: what the history
    rows say besides the change set and change (an accepted road preview's own)."""
    c = network(session, name)
    lock_topology(session, c)
    _change_set(session, c, set_id, open_only=True)
    counts = {"accepted": 0, "edited": 0, "stale": 0, "refused": 0}
    for change in _selected(session, set_id, selection, "proposed"):
        if change.edited and selection.bulk:
            counts["edited"] += 1
            continue
        savepoint = session.begin_nested()
        try:
            made = _apply(session, c, change,
                          {**(note or {}), "change_set": set_id, "change": change.id},
                          principal, action)
        except (NotFoundError, PreconditionFailedError):
            savepoint.rollback()
            counts["stale"] += 1
            continue
        except InvalidValueError:
            savepoint.rollback()
            counts["refused"] += 1
            continue
        savepoint.commit()
        session.execute(text(
            "UPDATE proposed_changes SET status = 'accepted', decided_by = :who, "
            "decided_at = clock_timestamp(), result_segment = :made WHERE id = :id"),
            {"who": principal.name, "made": made, "id": change.id})
        counts["accepted"] += 1
    return counts


def reject(session: Session, name: str, set_id: int, selection: Selection,
           principal: Principal) -> dict[str, int]:
    """Reject the selected proposals: nothing in the network changes; they are kept, marked
    (the next re-survey proposes again what it still sees)."""
    c = network(session, name)
    _change_set(session, c, set_id, open_only=True)
    rejected = session.execute(text(
        "UPDATE proposed_changes SET status = 'rejected', decided_by = :who, "
        "decided_at = clock_timestamp() WHERE id = ANY(:ids)"),
        {"who": principal.name,
         "ids": [r.id for r in _selected(session, set_id, selection, "proposed")]})
    return {"rejected": rejected.rowcount}  # type: ignore[attr-defined]


def _history_row(session: Session, c: colls.Collection, sid: int, change_id: int) -> Any:
    return session.execute(text(
        "SELECT old FROM segment_edits WHERE network_id = :n AND segment_id = :s "
        "AND action = ANY(:a) AND (new->>'change')::bigint = :c ORDER BY id DESC LIMIT 1"),
        {"n": c.network_id, "s": sid, "a": [ACCEPTED, PREVIEW_ACCEPTED],
         "c": change_id}).first()


def _remove_new_road(session: Session, c: colls.Collection, fid: int, note: dict[str, Any],
                     principal: Principal) -> None:
    """Delete an accepted new road, and where joining the network had split a road in two
    (a T junction) and nothing else joined there since, merge the two parts back."""
    ends = lock_feature(session, c, fid, None)["properties"]
    delete_segment(session, c, fid, None, principal, action=REVERTED, note=note)
    for node in {ends["source_node"], ends["target_node"]}:
        parts: Sequence[int] = session.execute(text(
            "SELECT s.id FROM road_segments s WHERE s.source_node = :node OR "
            "s.target_node = :node ORDER BY s.id"), {"node": node}).scalars().all()
        if len(parts) == 2 and session.execute(text(
                "SELECT 1 FROM segment_edits WHERE network_id = :n AND segment_id = :b "
                "AND action = 'split' AND (new->>'split_from')::bigint = :a"),
                {"n": c.network_id, "a": parts[0], "b": parts[1]}).first():
            merge_segments(session, c, {"segments": list(parts)}, None, principal)


EDITABLE = ("lanes_forward", "lanes_backward", "speed_limit_kph", "oneway", "road_class",
            "is_junction", "name", "surface", "width_m", "external_id", "attrs")


def revert(session: Session, name: str, set_id: int, principal: Principal) -> dict[str, int]:
    """Undo every accepted change of the change set, newest first, as edits (history action
    ``resurvey-revert``): a moved segment gets its line back (a new version), an added road
    is deleted, a deleted one is created again from its history (a new id; the history row
    names the one it restores; a road a new one had split is merged back). Proposals not
    yet decided are rejected; the set is closed. Counts ``reverted`` and ``gone`` (a change
    whose segment was deleted or edited away since: left as it is)."""
    c = network(session, name)
    lock_topology(session, c)
    _change_set(session, c, set_id, open_only=True)
    counts = {"reverted": 0, "gone": 0}
    accepted = session.execute(text(
        "SELECT id, kind, segment_id, result_segment FROM proposed_changes "
        "WHERE change_set_id = :set AND status = 'accepted' "
        "ORDER BY decided_at DESC, id DESC"), {"set": set_id}).all()
    for change in accepted:
        note = {"change_set": set_id, "change": change.id}
        savepoint = session.begin_nested()
        try:
            if change.kind == "new":
                _remove_new_road(session, c, change.result_segment, note, principal)
            else:
                row = _history_row(session, c, change.segment_id, change.id)
                if row is None:
                    raise NotFoundError("no history of the accepted change")
                if change.kind == "moved":
                    feature = lock_feature(session, c, change.segment_id, None)
                    write_change(session, c, feature, {"geometry": row.old["geometry"]},
                                 principal, REVERTED, note=note)
                else:
                    old = row.old
                    create_segment(session, c, {
                        "type": "Feature", "geometry": old["geometry"],
                        "properties": {k: old[k] for k in EDITABLE if k in old}},
                        crs_.DEFAULT, principal, action=REVERTED,
                        note={**note, "restores": change.segment_id},
                        confidence=old.get("confidence"))
        except (NotFoundError, InvalidValueError):
            savepoint.rollback()
            counts["gone"] += 1
            continue
        savepoint.commit()
        counts["reverted"] += 1
    session.execute(text(
        "UPDATE proposed_changes SET status = CASE status WHEN 'accepted' THEN 'reverted' "
        "ELSE 'rejected' END, decided_by = :who, decided_at = clock_timestamp() "
        "WHERE change_set_id = :set AND status IN ('accepted', 'proposed')"),
        {"who": principal.name, "set": set_id})
    session.execute(text("UPDATE change_sets SET status = 'reverted' WHERE id = :id"),
                    {"id": set_id})
    return counts


CHANGE_SETS = (
    "SELECT c.id, w.name AS network, c.source, c.status, c.created_by, c.created_at, "
    "  c.counts, c.layer_version, "
    "  (SELECT json_object_agg(k, n) FROM (SELECT kind || ':' || status AS k, count(*) AS n "
    "     FROM proposed_changes p WHERE p.change_set_id = c.id GROUP BY 1) t) AS decided "
    "FROM change_sets c JOIN networks w ON w.id = c.network_id "
    "WHERE c.network_id = :n {where} ORDER BY c.id")


def _summary(row: Any) -> dict[str, Any]:
    return {"id": row.id, "network": row.network, "source": row.source, "status": row.status,
            "created_by": row.created_by, "created_at": row.created_at.isoformat(),
            "counts": row.counts, "layer_version": row.layer_version,
            "proposals": row.decided or {}}


def change_sets(session: Session, name: str) -> list[dict[str, Any]]:
    """The network's change sets, oldest first: source, status, counts per outcome, and per
    kind how many proposals are proposed / accepted / rejected / reverted."""
    c = network(session, name)
    rows = session.execute(text(CHANGE_SETS.format(where="")), {"n": c.network_id}).all()
    return [_summary(r) for r in rows]


def change_set(session: Session, name: str, set_id: int) -> dict[str, Any]:
    """One change set with its proposals as a GeoJSON FeatureCollection (``id`` the change's;
    properties kind, status, segment_id, edited, detail, attributes of a new road)."""
    c = network(session, name)
    row = session.execute(text(CHANGE_SETS.format(where="AND c.id = :id")),
                          {"n": c.network_id, "id": set_id}).first()
    if row is None:
        raise NotFoundError(f"network {name!r} has no change set {set_id}")
    features: list[Any] = session.execute(text(
        "SELECT json_build_object('type', 'Feature', 'id', id, "
        "'geometry', ST_AsGeoJSON(geom, 9)::json, 'properties', json_build_object("
        "'kind', kind, 'status', status, 'segment_id', segment_id, 'edited', edited, "
        "'detail', detail, 'attributes', attributes, 'result_segment', result_segment, "
        "'decided_by', decided_by)) FROM proposed_changes WHERE change_set_id = :id "
        "ORDER BY id"), {"id": set_id}).scalars().all()  # type: ignore[assignment]
    return {**_summary(row), "type": "FeatureCollection", "features": features}


def coverage_of_layer(session: Session, slug: str) -> tuple[BaseGeometry, int, int]:
    """(the union of a layer's source footprints in lon/lat, its id, its version), the row
    share-locked so the layer cannot be re-ingested until the transaction ends."""
    layer = session.execute(text("SELECT id, version FROM layers WHERE slug = :slug "
                                 "FOR SHARE"), {"slug": slug}).first()
    outline: str | None = None if layer is None else session.execute(text(
        "SELECT ST_AsGeoJSON(ST_Transform(ST_Union(footprint), 4326)) FROM raster_sources "
        "WHERE layer_id = :id"), {"id": layer.id}).scalar()
    if layer is None or outline is None:
        raise NotFoundError(f"no raster layer {slug!r} with sources (see `ugvmap layers list`)")
    return shape(json.loads(outline)), int(layer.id), int(layer.version)
