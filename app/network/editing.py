"""Attribute (and geometry) edits of road segments with optimistic concurrency and history.

Why a row lock plus a version check: the version in ``If-Match`` is compared with the row
while it is locked (``SELECT ... FOR UPDATE``), so of N concurrent editors holding the same
version exactly one wins and the rest get 412; the history row is written in the same
transaction, so the history has no gaps and never records an edit that did not happen.
"""

from __future__ import annotations

import json
import math
from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.errors import (
    InvalidValueError,
    PreconditionFailedError,
    PreconditionRequiredError,
)
from app.network import collections as colls
from app.network.tokens import Principal
from app.network.validation import field_errors, lanes_consistent, merge_patch

FEATURE_KEYS = {"type", "id", "properties", "geometry", "links"}
GRID_DEG = 1e-7


def unprocessable(errors: dict[str, str]) -> InvalidValueError:
    """One 422 naming every field that breaks a rule, so a form can mark them all at once."""
    return InvalidValueError("; ".join(f"{k}: {v}" for k, v in errors.items()),
                             errors=errors)


def parse_if_match(header: str | None, count: int = 1) -> list[int]:
    """The versions an ``If-Match`` header names: ``"3"`` / ``W/"3"`` / ``3`` -> [3]; a write
    on ``count`` features (merge) names each one's ETag, comma-separated, in the order of the
    request. Missing -> 428; anything else matches nothing -> 412."""
    if header is None or not header.strip():
        raise PreconditionRequiredError(
            "If-Match with the feature's ETag (its version) is required" if count == 1 else
            f"If-Match with the ETags of the {count} segments, in order, is required")
    versions = []
    for tag in header.split(","):
        value = tag.strip().removeprefix("W/").strip('"')
        if not value.isascii() or not value.isdigit() or len(value) > 9:
            raise PreconditionFailedError("If-Match must be the ETag of the current version")
        versions.append(int(value))
    if len(versions) != count:
        raise PreconditionFailedError(f"If-Match must name {count} ETag(s), one per segment")
    return versions


def split_body(body: Any) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """A merge patch of the feature (``{"properties": .., "geometry": ..}``) or of its
    properties alone -> (property patch, new geometry or None)."""
    if not isinstance(body, dict):
        raise unprocessable({"body": "must be a JSON object"})
    if not body.keys() & {"properties", "geometry"}:
        return body, None
    unknown = body.keys() - FEATURE_KEYS
    if unknown:
        raise unprocessable({k[:100]: "is not a feature member" for k in unknown})
    properties = body.get("properties") or {}
    if not isinstance(properties, dict):
        raise unprocessable({"properties": "must be a JSON object"})
    if "geometry" in body and body["geometry"] is None:
        raise unprocessable({"geometry": "cannot be removed"})
    return properties, body.get("geometry")


def _check_line(geometry: Any, start: list[float], end: list[float]) -> str | None:
    if not isinstance(geometry, dict) or geometry.get("type") != "LineString":
        return "must be a GeoJSON LineString"
    coords = geometry.get("coordinates")
    if not isinstance(coords, list) or not 2 <= len(coords) <= 100_000:
        return "must have 2 to 100000 positions"
    for c in coords:
        if not isinstance(c, list) or len(c) != 2 or not all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in c):
            return "positions must be [lon, lat] pairs of finite numbers"
        if not (-180 <= c[0] <= 180 and -90 <= c[1] <= 90):
            return "positions must be within lon -180..180, lat -90..90"
    if any(abs(a - b) > GRID_DEG for a, b in zip(coords[0] + coords[-1], start + end,
                                                 strict=True)):
        return "must start and end at the segment's nodes (topology is kept)"
    return None


def _node_coords(session: Session, node_id: int) -> list[float]:
    geometry: str = session.execute(text("SELECT ST_AsGeoJSON(geom, 15) FROM road_nodes "
                                    "WHERE id = :id"), {"id": node_id}).scalar_one()
    return json.loads(geometry)["coordinates"]


def lock_segment(session: Session, c: colls.Collection, fid: int,
                 expected: int) -> dict[str, Any]:
    """Lock the segment row; 404 if absent, 412 if its version is not ``expected``."""
    feature = colls.get_item(session, c, fid, for_update=True)
    current = feature["properties"]["version"]
    if current != expected:
        raise PreconditionFailedError(f"the segment is at version {current}, not {expected}; "
                                      "reload it and apply your change again",
                                      headers={"ETag": f'"{current}"'})
    return feature


def write_change(session: Session, c: colls.Collection, feature: dict[str, Any],
                 new: dict[str, Any], principal: Principal, action: str) -> dict[str, Any]:
    """Apply full new values of changed columns (``geometry`` as GeoJSON) and log them."""
    props = feature["properties"]
    old = {k: (feature["geometry"] if k == "geometry" else props[k]) for k in new}
    changed = {k: v for k, v in new.items() if old[k] != v}
    if not changed:
        return feature
    assignments = [f"{k} = :{k}" for k in changed if k not in ("geometry", "attrs")]
    params: dict[str, Any] = {k: v for k, v in changed.items()
                              if k not in ("geometry", "attrs")}
    if "attrs" in changed:
        assignments.append("attrs = CAST(:attrs AS jsonb)")
        params["attrs"] = json.dumps(changed["attrs"])
    if "geometry" in changed:
        assignments.append("geom = ST_SetSRID(ST_GeomFromGeoJSON(:geometry), 4326)")
        assignments.append("length_m = ST_Length(ST_SetSRID(ST_GeomFromGeoJSON(:geometry), "
                           "4326)::geography)")
        params["geometry"] = json.dumps(changed["geometry"])
    version: int | None = session.execute(text(
        f"UPDATE road_segments SET {', '.join(assignments)}, version = version + 1, "
        "updated_at = now(), updated_by = :who WHERE id = :id AND version = :version "
        "RETURNING version"),
        {**params, "who": principal.name, "id": feature["id"],
         "version": props["version"]}).scalar_one()
    log_edit(session, c, feature["id"], action, props["version"], version, principal,
             {k: old[k] for k in changed}, changed)
    return colls.get_item(session, c, feature["id"])


def log_edit(session: Session, c: colls.Collection, segment_id: int, action: str,
             version_from: int | None, version_to: int | None, principal: Principal,
             old: dict[str, Any] | None, new: dict[str, Any] | None) -> None:
    """Append the edit to ``segment_edits`` in the edit's own transaction, so history never misses a
    committed change."""
    session.execute(text(
        "INSERT INTO segment_edits (network_id, segment_id, action, version_from, version_to, "
        "edited_by, old, new) VALUES (:n, :s, :a, :vf, :vt, :who, "
        "CAST(:old AS jsonb), CAST(:new AS jsonb))"),
        {"n": c.network_id, "s": segment_id, "a": action, "vf": version_from,
         "vt": version_to, "who": principal.name,
         "old": None if old is None else json.dumps(old),
         "new": None if new is None else json.dumps(new)})


def patch_segment(session: Session, c: colls.Collection, fid: int, expected: int,
                  body: Any, principal: Principal) -> dict[str, Any]:
    """Apply a JSON merge patch to a segment: validate every field first (422 naming each), then
    check the version (412) and write one new version."""
    properties, geometry = split_body(body)
    errors = field_errors(properties)
    if errors:
        raise unprocessable(errors)
    feature = lock_segment(session, c, fid, expected)
    props = feature["properties"]
    new = {k: (merge_patch(props["attrs"], v) if k == "attrs" else v)
           for k, v in properties.items()}
    if properties.keys() & {"oneway", "lanes_forward", "lanes_backward"}:
        errors = lanes_consistent({**props, **new})
    if geometry is not None:
        start = _node_coords(session, props["source_node"])
        end = _node_coords(session, props["target_node"])
        problem = _check_line(geometry, start, end)
        if problem:
            errors["geometry"] = problem
        else:  # ends snapped onto the nodes exactly, as validate requires
            coords = [start, *geometry["coordinates"][1:-1], end]
            new["geometry"] = {"type": "LineString", "coordinates": coords}
    if errors:
        raise unprocessable(errors)
    return write_change(session, c, feature, new, principal, "update")


def history(session: Session, c: colls.Collection, fid: int) -> list[dict[str, Any]]:
    """The segment's edits, oldest first; a deleted segment's too (its last edit is the
    deletion, with the whole segment as ``old``). 404 if the collection never had it."""
    rows = session.execute(text(
        "SELECT action, version_from, version_to, edited_by, edited_at, old, new "
        "FROM segment_edits WHERE network_id = :n AND segment_id = :s ORDER BY id"),
        {"n": c.network_id, "s": fid}).all()
    if not rows:
        colls.get_item(session, c, fid)
    return [{**r._mapping, "edited_at": r.edited_at.isoformat()} for r in rows]


def revert_segment(session: Session, c: colls.Collection, fid: int, to_version: int,
                   expected: int, principal: Principal) -> dict[str, Any]:
    """Restore the attributes (and geometry) the segment had at ``to_version``, as a new
    version: history only grows, so a revert can itself be reverted."""
    feature = lock_segment(session, c, fid, expected)
    current = feature["properties"]["version"]
    if not 1 <= to_version <= current:
        raise unprocessable({"to": f"must be a version from 1 to {current}"})
    edits = session.execute(text(
        "SELECT version_to, action, old FROM segment_edits "
        "WHERE network_id = :n AND segment_id = :s AND version_to > :v AND old IS NOT NULL "
        "ORDER BY version_to DESC"),
        {"n": c.network_id, "s": fid, "v": to_version}).all()
    if [e.version_to for e in edits] != list(range(current, to_version, -1)):
        raise unprocessable({"to": f"the history does not reach back to version {to_version}"})
    if any(e.action not in ("update", "revert") for e in edits):
        raise unprocessable({"to": "cannot revert across a split or merge (topology changed)"})
    restored: dict[str, Any] = {}
    for edit in edits:
        restored.update(edit.old)
    return write_change(session, c, feature, restored, principal, "revert")
