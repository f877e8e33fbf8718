"""Segment features as OGC API Features Part 4 edits them: PATCH (a JSON merge patch of the
attributes and/or the line), PUT (the whole feature replaced) and POST (a new road, noded into
the network at its ends). Deleting is :mod:`app.network.segment_deletion`; splitting and
merging, :mod:`app.network.topology_edits`.

Topology rules, the ones ``ugvmap network validate`` checks:

- a changed line (PATCH, PUT) must still start and end at the segment's nodes; its ends are
  then set onto the nodes exactly. Moving an end moves the node (PATCH the node), which
  drags every segment meeting there along;
- a created line is noded at its ends only: an end within :data:`SNAP_M` of a node joins that
  node; else an end within :data:`SNAP_M` of a segment splits that segment there (a T
  junction); else it gets a new endpoint node. Lines it crosses on the way are not noded
  (bridges stay bridges; split the crossed road to connect them). It must join two different
  nodes, be at least :data:`MIN_LENGTH_M` long and not duplicate a segment.
"""

from __future__ import annotations

import json
import math
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
from app.network.segment_rows import insert_segments, on_nodes
from app.network.tokens import Principal
from app.network.topology_edits import split_at
from app.network.validation import lanes_consistent, merge_patch

GRID_DEG = 1e-7
"""How far (degrees, ~1 cm) a changed line's end may lie from its node: it is then set onto it."""
SNAP_M = 0.5
"""A created line's end this close to a node joins it; this close to a segment splits it."""
MIN_LENGTH_M = 0.01
LANE_KEYS = {"oneway", "lanes_forward", "lanes_backward"}


def _node_coords(session: Session, node_id: int) -> list[float]:
    geometry: str = session.execute(text("SELECT ST_AsGeoJSON(geom, 15) FROM road_nodes "
                                    "WHERE id = :id"), {"id": node_id}).scalar_one()
    return json.loads(geometry)["coordinates"]


def _line_on_nodes(session: Session, props: dict[str, Any], raw: Any, crs: crs_.Crs
                   ) -> tuple[dict[str, Any] | None, str | None]:
    """The new line with its ends set exactly onto the segment's nodes, or why it is none."""
    geometry, problem = parse_geometry(session, raw, "LineString", crs)
    if geometry is None:
        return None, problem
    start = _node_coords(session, props["source_node"])
    end = _node_coords(session, props["target_node"])
    coords = geometry["coordinates"]
    if any(abs(a - b) > GRID_DEG for a, b in zip(coords[0] + coords[-1], start + end,
                                                 strict=True)):
        return None, ("must start and end at the segment's nodes (topology is kept; move a "
                      "node to move the ends of its segments)")
    return {"type": "LineString", "coordinates": [start, *coords[1:-1], end]}, None


def _write(session: Session, c: colls.Collection, feature: dict[str, Any],
           new: dict[str, Any], raw_geometry: Any, crs: crs_.Crs, principal: Principal,
           action: str, conditional: bool) -> dict[str, Any]:
    """Check the final state (lanes against one-way, the line on its nodes) and write it."""
    props = feature["properties"]
    errors = lanes_consistent({**props, **new}) if new.keys() & LANE_KEYS else {}
    if raw_geometry is not None:
        line, problem = _line_on_nodes(session, props, raw_geometry, crs)
        if line is None:
            errors["geometry"] = problem or "is not valid"
        else:
            new["geometry"] = line
    if errors:
        raise unprocessable(errors)
    return write_change(session, c, feature, new, principal, action, conditional=conditional)


def patch_segment(session: Session, c: colls.Collection, fid: int, expected: int | None,
                  body: Any, crs: crs_.Crs, principal: Principal) -> dict[str, Any]:
    """Apply a JSON merge patch to a segment: validate every field first (422 naming each), then
    check the version (412) and write one new version."""
    properties, raw_geometry = patch_parts(body, "segments")
    feature = lock_feature(session, c, fid, expected)
    attrs = feature["properties"]["attrs"]
    new = {k: (merge_patch(attrs, v) if k == "attrs" else v) for k, v in properties.items()}
    return _write(session, c, feature, new, raw_geometry, crs, principal, "update",
                  expected is not None)


def replace_segment(session: Session, c: colls.Collection, fid: int, expected: int | None,
                    body: Any, crs: crs_.Crs, principal: Principal) -> dict[str, Any]:
    """PUT: the whole feature replaced (attributes not given take their defaults; the line
    keeps its nodes), as one new version."""
    values, raw_geometry = whole_parts(body, "segments")
    feature = lock_feature(session, c, fid, expected)
    return _write(session, c, feature, values, raw_geometry, crs, principal, "replace",
                  expected is not None)


NEAR = ("ST_DWithin(geom, ST_SetSRID(ST_MakePoint(:x, :y), 4326), :deg) AND "
        "ST_DWithin(geom::geography, ST_SetSRID(ST_MakePoint(:x, :y), 4326)::geography, :m)")
NEAREST = "ORDER BY geom <-> ST_SetSRID(ST_MakePoint(:x, :y), 4326) LIMIT 1"


def _near(c: colls.Collection, position: list[float]) -> dict[str, float]:
    """Query parameters of a position and of :data:`SNAP_M` in degrees there (a generous
    bounding distance for the index; the exact test is on geography)."""
    lon, lat = position
    degrees = SNAP_M / (111_000 * max(math.cos(math.radians(lat)), 0.01))
    return {"x": lon, "y": lat, "deg": degrees, "m": SNAP_M, "n": c.network_id}


def nearest_node(session: Session, c: colls.Collection, position: list[float]) -> int | None:
    """The network's node nearest to ``position`` within :data:`SNAP_M`, locked."""
    node = session.execute(text(f"SELECT id FROM road_nodes WHERE network_id = :n AND {NEAR} "
                                f"{NEAREST} FOR UPDATE"), _near(c, position)).scalar()
    return None if node is None else int(node)


def split_nearest_road(session: Session, c: colls.Collection, position: list[float],
                       principal: Principal) -> int | None:
    """Split the segment nearest to ``position`` (within :data:`SNAP_M`) at the point of it
    nearest to ``position``; the new node, or None when no segment is that near."""
    road = session.execute(text(
        "SELECT id, ST_LineLocatePoint(geom, ST_SetSRID(ST_MakePoint(:x, :y), 4326)) AS f "
        f"FROM road_segments WHERE network_id = :n AND {NEAR} {NEAREST}"),
        _near(c, position)).first()
    if road is None:
        return None
    kept, _ = split_at(session, c, lock_feature(session, c, road.id, None), road.f, principal,
                       conditional=False)
    return int(kept["properties"]["target_node"])


def node_for_end(session: Session, c: colls.Collection, position: list[float],
                 principal: Principal) -> int:
    """The node a created line's end joins: an existing node near it, a new node splitting a
    segment near it, or a new endpoint node."""
    node = nearest_node(session, c, position)
    if node is None:
        node = split_nearest_road(session, c, position, principal)
    if node is not None:
        return node
    created: int = session.execute(text(
        "INSERT INTO road_nodes (network_id, geom, kind, updated_by) VALUES "
        "(:n, ST_SetSRID(ST_MakePoint(:x, :y), 4326), 'endpoint', :who) RETURNING id"),
        {**_near(c, position), "who": principal.name}).scalar_one()
    return created


def create_segment(session: Session, c: colls.Collection, body: Any, crs: crs_.Crs,
                   principal: Principal, *, action: str = "create",
                   note: dict[str, Any] | None = None,
                   confidence: float | None = None) -> dict[str, Any]:
    """POST: a new road from a whole GeoJSON feature, noded into the network at its ends; its
    history starts with an ``action`` row (``create``) holding what was created, and
    ``note``. A road from an extraction (an accepted preview) keeps its ``confidence``, which
    no edit may set."""
    values, raw_geometry = whole_parts(body, "segments")
    errors = lanes_consistent(values)
    line, problem = parse_geometry(session, raw_geometry, "LineString", crs)
    if line is None:
        errors["geometry"] = problem or "is not valid"
    elif session.execute(text("SELECT ST_Length(ST_SetSRID(ST_GeomFromGeoJSON(:g), 4326)"
                              "::geography)"), {"g": json.dumps(line)}).scalar_one() \
            < MIN_LENGTH_M:
        errors["geometry"] = f"must be at least {MIN_LENGTH_M} m long"
    if errors or line is None:
        raise unprocessable(errors)
    coords = line["coordinates"]
    lock_topology(session, c)
    source = node_for_end(session, c, coords[0], principal)
    target = node_for_end(session, c, coords[-1], principal)
    if source == target:
        raise unprocessable({"geometry": "must join two different nodes (both ends are at "
                                         f"node {source}; draw a closed road as two segments)"})
    stored = on_nodes("ST_SetSRID(ST_GeomFromGeoJSON(:g), 4326)", ":source", ":target")
    duplicate = session.execute(text(
        "SELECT id FROM road_segments WHERE network_id = :n "
        "AND LEAST(source_node, target_node) = LEAST(:source, :target) "
        "AND GREATEST(source_node, target_node) = GREATEST(:source, :target) "
        f"AND ST_Equals(geom, {stored}) LIMIT 1"),
        {"n": c.network_id, "source": source, "target": target, "g": json.dumps(line)}
    ).scalar()
    if duplicate is not None:
        raise unprocessable({"geometry": f"duplicates segment {duplicate}"})
    attributes = {k: v for k, v in values.items() if k != "attrs"}
    fid: int = session.execute(text(insert_segments({
        "network_id": ":n", "source_node": ":source", "target_node": ":target",
        "geom": stored, "updated_by": ":who",
        "attrs": "CAST(:attrs AS jsonb)", "confidence": ":confidence",
        **{k: f":{k}" for k in attributes}}, returning=True)),
        {**attributes, "n": c.network_id, "source": source, "target": target,
         "g": json.dumps(line), "who": principal.name, "confidence": confidence,
         "attrs": json.dumps(values["attrs"])}).scalar_one()
    colls.settle_nodes(session, [source, target])
    created = colls.get_item(session, c, fid)
    extracted = {} if confidence is None else {"confidence": confidence}
    log_edit(session, c, fid, action, None, 1, principal, None,
             {**values, **extracted, "geometry": created["geometry"], **(note or {})})
    return created
