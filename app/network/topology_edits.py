"""Admin edits that change the topology: split a segment at a point, merge two segments
through a node only they share. Both keep the invariants ``ugvmap network validate`` checks:
segment ends coincide with their nodes, node kinds match degrees, no duplicates.
"""

from __future__ import annotations

import json
from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.network import collections as colls
from app.network.editing import (
    lock_feature,
    log_edit,
    unprocessable,
    write_change,
)
from app.network.segment_rows import insert_segments, on_nodes
from app.network.tokens import Principal
from app.params import parse_number, parse_position

# Attributes that must agree before two segments can become one.
MERGE_MUST_MATCH = ("lanes_forward", "lanes_backward", "speed_limit_kph", "oneway",
                    "road_class", "is_junction", "name", "surface", "width_m")
FLIPPED_ONEWAY = {"forward": "backward", "backward": "forward", "none": "none"}
MIN_PART_M = 0.01


def _fraction(session: Session, feature: dict[str, Any], body: Any) -> float:
    """The split position as a fraction of the length, strictly inside the segment and at least
    :data:`MIN_PART_M` from either end (a sliver would be a degenerate line, not a segment)."""
    if not isinstance(body, dict) or len(body.keys() & {"fraction", "point"}) != 1:
        raise unprocessable({"body": 'give exactly one of "fraction" (0..1) or "point" '
                                     "([lon, lat])"})
    unknown = sorted(body.keys() - {"fraction", "point"})
    if unknown:
        raise unprocessable({k[:100]: "is not a split parameter" for k in unknown})
    if "fraction" in body:
        fraction = parse_number(body["fraction"], "fraction", low=0, high=1)
    else:
        lon, lat = parse_position(body["point"], "point")
        fraction = session.execute(text(
            "SELECT ST_LineLocatePoint(geom, ST_SetSRID(ST_MakePoint(:x, :y), 4326)) "
            "FROM road_segments WHERE id = :id"),
            {"x": lon, "y": lat, "id": feature["id"]}).scalar_one()
    length = feature["properties"]["length_m"]
    if min(fraction, 1 - fraction) * length < MIN_PART_M:
        raise unprocessable({"fraction": f"the split point must lie inside the segment, at "
                                         f"least {MIN_PART_M} m from either end"})
    return fraction


def split_segment(session: Session, c: colls.Collection, fid: int, expected: int | None,
                  body: Any, principal: Principal) -> dict[str, Any]:
    """Split at a fraction of the length or at the point nearest to a given one. The original
    keeps its id (first part, new version); the second part is a new segment, same attributes."""
    feature = lock_feature(session, c, fid, expected)
    parts = split_at(session, c, feature, _fraction(session, feature, body), principal,
                     conditional=expected is not None)
    return {"type": "FeatureCollection", "features": list(parts)}


def split_at(session: Session, c: colls.Collection, feature: dict[str, Any], fraction: float,
             principal: Principal, *, conditional: bool = True
             ) -> tuple[dict[str, Any], dict[str, Any]]:
    """Split the locked segment ``feature`` at ``fraction`` of its length (at least
    :data:`MIN_PART_M` from either end) through a new node: (first part, keeping the id and
    gaining a version; second part, a new segment with the same attributes). Also how a
    created segment or node joins a road in its middle."""
    fid = feature["id"]
    halves = session.execute(text(
        "SELECT ST_AsGeoJSON(ST_LineSubstring(geom, 0, :f), 15), "
        "ST_AsGeoJSON(ST_LineSubstring(geom, :f, 1), 15) FROM road_segments WHERE id = :id"),
        {"f": fraction, "id": fid}).one()
    first, second = json.loads(halves[0]), json.loads(halves[1])
    cut = first["coordinates"][-1]
    second["coordinates"][0] = cut
    if len(first["coordinates"]) < 2 or cut in (first["coordinates"][0],
                                                  second["coordinates"][-1]):
        raise unprocessable({"fraction": "the split point is too close to an end"})
    node: int = session.execute(text(
        "INSERT INTO road_nodes (network_id, geom, kind, updated_by) VALUES "
        "(:n, ST_SetSRID(ST_MakePoint(:x, :y), 4326), 'node', :who) RETURNING id"),
        {"n": c.network_id, "x": cut[0], "y": cut[1], "who": principal.name}).scalar_one()
    old_target = feature["properties"]["target_node"]
    kept = write_change(session, c, feature, {"geometry": first, "target_node": node},
                        principal, "split", conditional=conditional)
    same = {c: c for c in (*colls.SEGMENT_ATTRIBUTES, "confidence")}  # both parts as sure
    new_id: int = session.execute(text(insert_segments({
        "network_id": "network_id", "source_node": ":node", "target_node": ":target",
        "geom": on_nodes("ST_SetSRID(ST_GeomFromGeoJSON(:g), 4326)", ":node", ":target"),
        "updated_by": ":who", **same},
        "road_segments WHERE id = :id", returning=True)),
        {"node": node, "target": old_target, "g": json.dumps(second), "who": principal.name,
         "id": fid}).scalar_one()
    log_edit(session, c, new_id, "split", None, 1, principal, None,
             {"split_from": fid, "geometry": second}, conditional=conditional)
    return kept, colls.get_item(session, c, new_id)


def _flipped(props: dict[str, Any]) -> dict[str, Any]:
    """The same road described in the opposite digitising direction."""
    return {**props, "oneway": FLIPPED_ONEWAY[props["oneway"]],
            "lanes_forward": props["lanes_backward"], "lanes_backward": props["lanes_forward"],
            "source_node": props["target_node"], "target_node": props["source_node"]}


def merged_confidence(a: dict[str, Any], b: dict[str, Any]) -> float | None:
    """The confidence of two segments joined into one: their length-weighted mean, over the
    ones extraction measured (None when neither was extracted)."""
    known = [(p["confidence"], max(p["length_m"], 1e-9)) for p in (a, b)
             if p["confidence"] is not None]
    if not known:
        return None
    return sum(c * length for c, length in known) / sum(length for _, length in known)


def merge_segments(session: Session, c: colls.Collection, body: Any,
                   expected: list[int] | None, principal: Principal) -> dict[str, Any]:
    """Merge two segments meeting at a node that no other segment uses; the first keeps its
    id and orientation, the second and the shared node are deleted. ``expected`` holds the
    versions the client saw, in the order of ``segments`` (412 if either moved on; None:
    whatever versions are current)."""
    if isinstance(body, dict) and body.keys() - {"segments"}:
        raise unprocessable({k[:100]: "is not a merge parameter"
                             for k in sorted(body.keys() - {"segments"})})
    ids = body.get("segments") if isinstance(body, dict) else None
    if not (isinstance(ids, list) and len(ids) == 2 and all(
            isinstance(i, int) and not isinstance(i, bool) and 0 < i < 2**63 for i in ids)
            and ids[0] != ids[1]):
        raise unprocessable({"segments": "must be two different segment ids"})
    given: list[int | None] = list(expected) if expected else [None, None]
    versions = dict(zip(ids, given, strict=True))
    locked = {i: lock_feature(session, c, i, versions[i]) for i in sorted(ids)}
    conditional = expected is not None
    a, b = locked[ids[0]], locked[ids[1]]
    pa, pb = a["properties"], b["properties"]
    shared = {pa["source_node"], pa["target_node"]} & {pb["source_node"], pb["target_node"]}
    if len(shared) != 1 or pa["source_node"] == pa["target_node"] \
            or pb["source_node"] == pb["target_node"]:
        raise unprocessable({"segments": "must meet at exactly one node and not be loops"})
    (node,) = shared
    degree: int = session.execute(text(
        "SELECT count(*) FROM road_segments WHERE source_node = :n OR target_node = :n"),
        {"n": node}).scalar_one()
    if degree != 2:
        raise unprocessable({"segments": f"node {node} joins {degree} segments, not just these "
                                         "two; merging would break the topology"})
    a_coords, b_coords = a["geometry"]["coordinates"], b["geometry"]["coordinates"]
    oriented_a = pa if pa["target_node"] == node else _flipped(pa)
    if pa["target_node"] != node:
        a_coords = a_coords[::-1]
    oriented_b = pb if pb["source_node"] == node else _flipped(pb)
    if pb["source_node"] != node:
        b_coords = b_coords[::-1]
    differ = [k for k in MERGE_MUST_MATCH if oriented_a[k] != oriented_b[k]]
    if differ:
        raise unprocessable({k: "differs between the two segments" for k in differ})
    coords = a_coords + b_coords[1:]
    if pa["target_node"] != node:  # keep a's own digitising direction
        coords = coords[::-1]
        new_ends = {"source_node": oriented_b["target_node"], "target_node": pa["target_node"]}
    else:
        new_ends = {"source_node": pa["source_node"], "target_node": oriented_b["target_node"]}
    session.execute(text("DELETE FROM road_segments WHERE id = :id"), {"id": b["id"]})
    log_edit(session, c, b["id"], "merge", pb["version"], None, principal,
             {**pb, "geometry": b["geometry"]}, {"merged_into": a["id"]},
             conditional=conditional)
    merged = write_change(session, c, a, {"geometry": {"type": "LineString",
                                                       "coordinates": coords}, **new_ends,
                                          "confidence": merged_confidence(pa, pb)},
                          principal, "merge", conditional=conditional)
    session.execute(text("DELETE FROM road_nodes WHERE id = :n"), {"n": node})
    return merged
