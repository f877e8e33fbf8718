"""Node features as OGC API Features Part 4 edits them, with the topology kept valid.

- PATCH / PUT: the attributes a node has of its own (``traffic_light``, ``external_id``) and
  its position. Moving a node moves the ends of every segment meeting there with it (each
  segment gains a version, its history action ``move-node``), since segment ends must lie on
  their nodes; a position where another node already is, is refused (nodes are not merged).
- POST: a node is where roads meet or end, so a new one must lie on a segment (within
  :data:`~app.network.segment_editing.SNAP_M`): the segment is split there, exactly as
  ``POST .../split`` does. Admin role, as a split.
- DELETE: only a node joining exactly two segments can go: they are merged into one, exactly
  as ``POST .../merge`` does (their attributes must agree). Endpoints go with their segment,
  junctions with their roads. Admin role, as a merge.

``kind`` and ``degree`` follow the segments and are read-only; the node's ``version`` (its
ETag) counts the edits of the node itself.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.network import collections as colls
from app.network import crs as crs_
from app.network.editing import (
    lock_feature,
    lock_topology,
    log_edit,
    unprocessable,
    write_change,
)
from app.network.feature_bodies import patch_parts, whole_parts
from app.network.geometry_input import parse_geometry
from app.network.segment_editing import GRID_DEG, SNAP_M, nearest_node, split_nearest_road
from app.network.tokens import Principal
from app.network.topology_edits import merge_segments


def _segments_of(c: colls.Collection) -> colls.Collection:
    return colls.Collection(c.network, c.network_id, "segments", c.title)


def _segment_ids(session: Session, node: int) -> list[int]:
    """The node's segments, locked (in id order, as every edit locks them)."""
    return list(session.execute(text(
        "SELECT id FROM road_segments WHERE source_node = :n OR target_node = :n "
        "ORDER BY id FOR UPDATE"), {"n": node}).scalars())


def _point(session: Session, raw: Any, crs: crs_.Crs) -> list[float]:
    point, problem = parse_geometry(session, raw, "Point", crs)
    if point is None:
        raise unprocessable({"geometry": problem or "is not valid"})
    coordinates: list[float] = point["coordinates"]
    return coordinates


def _vacant(session: Session, c: colls.Collection, node: int, position: list[float]) -> None:
    """Refuse a move onto a spot another node has (nodes are not merged)."""
    other = session.execute(text(
        "SELECT id FROM road_nodes WHERE network_id = :n AND id <> :id AND "
        "ST_DWithin(geom, ST_SetSRID(ST_MakePoint(:x, :y), 4326), :grid) LIMIT 1"),
        {"n": c.network_id, "id": node, "x": position[0], "y": position[1],
         "grid": GRID_DEG}).scalar()
    if other is not None:
        raise unprocessable({"geometry": f"node {other} is already there (nodes are not "
                                         "merged; delete or move one of them first)"})


def _move_segment_ends(session: Session, c: colls.Collection, node: int,
                       position: list[float], principal: Principal, conditional: bool) -> None:
    """Put every end of the node's segments at ``position``, where the node now is (the
    segment writes copy the node's stored geometry onto the line ends, so they are its very
    doubles)."""
    segments = _segments_of(c)
    for sid in _segment_ids(session, node):
        feature = lock_feature(session, segments, sid, None)
        coords = [list(p) for p in feature["geometry"]["coordinates"]]
        if feature["properties"]["source_node"] == node:
            coords[0] = position
        if feature["properties"]["target_node"] == node:
            coords[-1] = position
        write_change(session, segments, feature,
                     {"geometry": {"type": "LineString", "coordinates": coords}},
                     principal, "move-node", conditional=conditional)


def _write(session: Session, c: colls.Collection, feature: dict[str, Any],
           new: dict[str, Any], raw_geometry: Any, crs: crs_.Crs, principal: Principal,
           action: str, conditional: bool) -> dict[str, Any]:
    """Write the node, then (when it moved) its segments' ends onto its new position."""
    moved = False
    if raw_geometry is not None:
        position = _point(session, raw_geometry, crs)
        if position != feature["geometry"]["coordinates"]:
            _vacant(session, c, feature["id"], position)
            new["geometry"] = {"type": "Point", "coordinates": position}
            action, moved = "move", True
    written = write_change(session, c, feature, new, principal, action,
                           conditional=conditional)
    if moved:
        _move_segment_ends(session, c, feature["id"], position, principal, conditional)
    return written


def patch_node(session: Session, c: colls.Collection, fid: int, expected: int | None,
               body: Any, crs: crs_.Crs, principal: Principal) -> dict[str, Any]:
    """PATCH: a merge patch of the node's attributes and/or position."""
    properties, raw_geometry = patch_parts(body, "nodes")
    feature = lock_feature(session, c, fid, expected)
    return _write(session, c, feature, dict(properties), raw_geometry, crs, principal,
                  "update", expected is not None)


def replace_node(session: Session, c: colls.Collection, fid: int, expected: int | None,
                 body: Any, crs: crs_.Crs, principal: Principal) -> dict[str, Any]:
    """PUT: the node's attributes replaced (defaults for those not given), its position set."""
    values, raw_geometry = whole_parts(body, "nodes")
    feature = lock_feature(session, c, fid, expected)
    return _write(session, c, feature, values, raw_geometry, crs, principal, "replace",
                  expected is not None)


def create_node(session: Session, c: colls.Collection, body: Any, crs: crs_.Crs,
                principal: Principal) -> dict[str, Any]:
    """POST: a node on a segment, which is split there; the node is where the split falls
    (the nearest point of the segment)."""
    values, raw_geometry = whole_parts(body, "nodes")
    position = _point(session, raw_geometry, crs)
    segments = _segments_of(c)
    lock_topology(session, c)
    existing = nearest_node(session, c, position)
    if existing is not None:
        raise unprocessable({"geometry": f"node {existing} is already there (within "
                                         f"{SNAP_M} m)"})
    node = split_nearest_road(session, segments, position, principal)
    if node is None:
        raise unprocessable({"geometry": f"must lie on a segment (within {SNAP_M} m), which "
                                         "it splits: nodes are where roads meet or end; draw "
                                         "a segment to add a road"})
    session.execute(text("UPDATE road_nodes SET traffic_light = :traffic_light, "
                         "external_id = :external_id WHERE id = :id"), {**values, "id": node})
    created = colls.get_item(session, c, node)
    log_edit(session, c, node, "create", None, 1, principal, None,
             {**values, "geometry": created["geometry"]})
    return created


def delete_node(session: Session, c: colls.Collection, fid: int, expected: int | None,
                principal: Principal) -> None:
    """DELETE: a node between two segments, which are merged through it."""
    feature = lock_feature(session, c, fid, expected)
    ids = _segment_ids(session, fid)
    # Read once the network's edit lock is held (lock_feature), so after any edit this
    # request waited for: it says what is there now (it once said "joins 2 segment ends"
    # of a node whose other segment a concurrent deletion had just removed).
    degree = feature["properties"]["degree"]
    if degree != 2 or len(ids) != 2:
        ends = "1 segment end" if degree == 1 else f"{degree} segment ends"
        raise unprocessable({"id": f"node {fid} joins {ends}: only a node between two "
                                   "segments can be deleted (they are merged); an endpoint "
                                   "goes with its segment"})
    merge_segments(session, _segments_of(c), {"segments": ids}, None, principal)
    log_edit(session, c, fid, "delete", feature["properties"]["version"], None, principal,
             {**feature["properties"], "geometry": feature["geometry"]}, None,
             conditional=expected is not None)
