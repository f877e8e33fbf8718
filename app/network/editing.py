"""What every edit of a segment or node shares: the precondition, the row lock, the write of
one new version, and its history row.

Why a row lock plus a version check: the version in ``If-Match`` is compared with the row
while it is locked (``SELECT ... FOR UPDATE``), so of N concurrent editors holding the same
version exactly one wins and the rest get 412; the history row is written in the same
transaction, so the history has no gaps and never records an edit that did not happen.

The If-Match policy (``UGVMAP_IF_MATCH``): a stale ``If-Match`` is always a 412, so a client
that sends one (the web map, scripts) never overwrites a change it has not seen. A write
*without* ``If-Match`` is refused with 428 under ``required``; under ``optional`` (the default,
because QGIS never sends ``If-Match`` and editing from QGIS is what OGC API Features Part 4 is
for) it applies to the version current when the row is locked, and its history row says so
(``conditional: false``) while keeping the overwritten version number and values: a lost
update is then visible in the history and undone with ``revert?to=<that version>``.
"""

from __future__ import annotations

import json
from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.errors import InvalidValueError, PreconditionFailedError, PreconditionRequiredError
from app.network import collections as colls
from app.network import lane_ranges
from app.network.segment_rows import geodesic_length, on_nodes
from app.network.tokens import Principal
from app.settings import get_settings

# History table and id column of each collection kind.
HISTORY: dict[colls.Kind, tuple[str, str]] = {"segments": ("segment_edits", "segment_id"),
                                              "nodes": ("node_edits", "node_id"),
                                              "lanes": ("lane_boundary_edits", "boundary_id")}
# Edits a revert may undo: attribute and geometry changes. A split, merge or node move
# changed the topology (restoring one segment's old line would detach it from its nodes).
REVERTIBLE = ("update", "replace", "revert", "resurvey", "resurvey-revert", "lanes-from-paint",
              "lanes")


def unprocessable(errors: dict[str, str]) -> InvalidValueError:
    """One 422 naming every field that breaks a rule, so a form can mark them all at once."""
    return InvalidValueError.naming(errors)


def parse_if_match(header: str | None, count: int = 1) -> list[int] | None:
    """The versions an ``If-Match`` header names: ``"3"`` / ``W/"3"`` / ``3`` -> [3]; a write
    on ``count`` features (merge) names each one's ETag, comma-separated, in the order of the
    request. None when the write is unconditional: ``If-Match: *`` (RFC 9110: any current
    version) or no header where the policy allows it (else 428). Anything else matches
    nothing -> 412."""
    value = (header or "").strip()
    if value == "*":
        return None
    if not value:
        if get_settings().if_match == "required":
            raise PreconditionRequiredError(
                "If-Match with the feature's ETag (its version) is required" if count == 1
                else f"If-Match with the ETags of the {count} segments, in order, is required")
        return None
    versions = []
    for tag in value.split(","):
        tag = tag.strip().removeprefix("W/").strip('"')
        if not tag.isascii() or not tag.isdigit() or len(tag) > 9:
            raise PreconditionFailedError("If-Match must be the ETag of the current version")
        versions.append(int(tag))
    if len(versions) != count:
        raise PreconditionFailedError(f"If-Match must name {count} ETag(s), one per segment")
    return versions


def expected_version(header: str | None) -> int | None:
    """The one version ``If-Match`` names for a write on one feature (None: unconditional)."""
    versions = parse_if_match(header)
    return None if versions is None else versions[0]


def lock_topology(session: Session, c: colls.Collection) -> None:
    """The network's edit lock, held until the transaction ends: every edit takes it before
    any row lock (:func:`lock_feature` does), so the edits of a network run one at a time
    and take their row locks in one order.

    Why before everything: edits lock rows in different orders (a node move: the node, then
    its segments; a segment deletion: the segment, then its nodes; a created segment: the
    nodes near its ends), and two of them interleaved deadlocked. Nothing is lost by it:
    each edit's first write bumps the network's version row, which serialised them from
    there on anyway. It also keeps two edits looking for a node at one spot from each
    creating one."""
    session.execute(text("SELECT pg_advisory_xact_lock(hashtext('ugvmap.topology'), :n)"),
                    {"n": c.network_id})


def lock_feature(session: Session, c: colls.Collection, fid: int,
                 expected: int | None) -> dict[str, Any]:
    """Lock the feature's row; 404 if absent, 412 if ``expected`` is not its version (None:
    any version, an unconditional write). The network's edit lock first (:func:`lock_topology`)."""
    lock_topology(session, c)
    feature = colls.get_item(session, c, fid, for_update=True)
    current = feature["properties"]["version"]
    if expected is not None and current != expected:
        raise PreconditionFailedError(f"the {c.kind[:-1]} is at version {current}, not "
                                      f"{expected}; reload it and apply your change again",
                                      current=current)
    return feature


def write_change(session: Session, c: colls.Collection, feature: dict[str, Any],
                 new: dict[str, Any], principal: Principal, action: str, *,
                 conditional: bool = True, note: dict[str, Any] | None = None
                 ) -> dict[str, Any]:
    """Apply full new values of changed columns (``geometry`` as lon/lat GeoJSON; a segment's
    ends are set onto its nodes' geometries as stored, and its length follows) as one new
    version, and log it (with ``note`` in the history row's ``new``: why, e.g. the change
    set an accepted re-survey change came from)."""
    props = feature["properties"]
    if lane_ranges.KEY in new:  # not a column: the segment's rows of segment_lanes
        props = {**props, lane_ranges.KEY: lane_ranges.read_ranges(session, feature["id"])}
    old = {k: (feature["geometry"] if k == "geometry" else props[k]) for k in new}
    changed = {k: v for k, v in new.items() if old[k] != v}
    if not changed:
        return feature
    special = ("geometry", "attrs", lane_ranges.KEY)
    assignments = [f"{k} = :{k}" for k in changed if k not in special]
    params: dict[str, Any] = {k: v for k, v in changed.items() if k not in special}
    if lane_ranges.KEY in changed:
        lane_ranges.store_ranges(session, c.network_id, feature["id"], changed[lane_ranges.KEY])
    if "attrs" in changed:
        assignments.append("attrs = CAST(:attrs AS jsonb)")
        params["attrs"] = json.dumps(changed["attrs"])
    if "geometry" in changed:
        geom = "ST_SetSRID(ST_GeomFromGeoJSON(:geometry), 4326)"
        if c.kind == "segments":  # its ends its nodes' (new) geometries, to the last bit
            geom = on_nodes(geom, *(f":{k}" if k in changed else f"road_segments.{k}"
                                    for k in ("source_node", "target_node")))
            assignments.append(f"length_m = {geodesic_length(geom)}")
        assignments.append(f"geom = {geom}")
        params["geometry"] = json.dumps(changed["geometry"])
    version: int | None = session.execute(text(
        f"UPDATE {c.table} SET {''.join(a + ', ' for a in assignments)}version = version + 1, "
        "updated_at = now(), updated_by = :who WHERE id = :id AND version = :version "
        "RETURNING version"),
        {**params, "who": principal.name, "id": feature["id"],
         "version": props["version"]}).scalar_one()
    log_edit(session, c, feature["id"], action, props["version"], version, principal,
             {k: old[k] for k in changed}, {**changed, **(note or {})},
             conditional=conditional)
    return colls.get_item(session, c, feature["id"])


def log_edit(session: Session, c: colls.Collection, fid: int, action: str,
             version_from: int | None, version_to: int | None, principal: Principal,
             old: dict[str, Any] | None, new: dict[str, Any] | None, *,
             conditional: bool = True) -> None:
    """Append the edit to the kind's history table in the edit's own transaction, so history
    never misses a committed change."""
    table, column = HISTORY[c.kind]
    session.execute(text(
        f"INSERT INTO {table} (network_id, {column}, action, version_from, version_to, "
        "edited_by, conditional, old, new) VALUES (:n, :s, :a, :vf, :vt, :who, :cond, "
        "CAST(:old AS jsonb), CAST(:new AS jsonb))"),
        {"n": c.network_id, "s": fid, "a": action, "vf": version_from, "vt": version_to,
         "who": principal.name, "cond": conditional,
         "old": None if old is None else json.dumps(old),
         "new": None if new is None else json.dumps(new)})


def history(session: Session, c: colls.Collection, fid: int) -> str:
    """The feature's edits, oldest first, as the JSON text of a list; a deleted one's too (its
    last edit is the deletion, with the whole feature as ``old``). 404 if the collection never
    had it.

    Why PostgreSQL writes the JSON: every row ever stored must read back. A row written
    before ``attrs`` had a depth limit may nest deeper than Python's serializers go (pydantic
    stops at 255 levels, and a history that answered 500 stayed so for good); PostgreSQL
    writes any ``jsonb`` it holds."""
    table, column = HISTORY[c.kind]
    edits: str | None = session.execute(text(
        "SELECT json_agg(json_build_object('action', action, 'version_from', version_from, "
        "'version_to', version_to, 'edited_by', edited_by, 'edited_at', edited_at, "
        "'conditional', conditional, 'old', old, 'new', new) ORDER BY id)::text "
        f"FROM {table} WHERE network_id = :n AND {column} = :s"),
        {"n": c.network_id, "s": fid}).scalar_one()
    if edits is None:
        colls.get_item(session, c, fid)
    return edits or "[]"


def revert_feature(session: Session, c: colls.Collection, fid: int, to_version: int,
                   expected: int | None, principal: Principal) -> dict[str, Any]:
    """Restore the attributes (and geometry) the feature had at ``to_version``, as a new
    version: history only grows, so a revert can itself be reverted."""
    feature = lock_feature(session, c, fid, expected)
    current = feature["properties"]["version"]
    if not 1 <= to_version <= current:
        raise unprocessable({"to": f"must be a version from 1 to {current}"})
    table, column = HISTORY[c.kind]
    edits = session.execute(text(
        f"SELECT version_to, action, old FROM {table} "
        f"WHERE network_id = :n AND {column} = :s AND version_to > :v AND old IS NOT NULL "
        "ORDER BY version_to DESC"),
        {"n": c.network_id, "s": fid, "v": to_version}).all()
    if [e.version_to for e in edits] != list(range(current, to_version, -1)):
        raise unprocessable({"to": f"the history does not reach back to version {to_version}"})
    if any(e.action not in REVERTIBLE for e in edits):
        raise unprocessable({"to": "cannot revert across a split, merge or node move "
                                   "(the topology changed)"})
    restored: dict[str, Any] = {}
    for edit in edits:
        restored.update(edit.old)
    return write_change(session, c, feature, restored, principal, "revert",
                        conditional=expected is not None)
