"""Lane boundary features as OGC API Features Part 4 edits them (``{network}-lanes``).

- PATCH / PUT: a boundary's ``kind``, ``colour``, ``width_m``, ``position`` and ``source``, and
  its line (a person redrawing a line extraction misplaced). A new line gets the stretch of its
  segment it runs along again (its ends located on the segment); its ``offset_m`` is cleared
  (the Lanelet2 export measures the line itself).
- DELETE: the boundary goes (its history row keeps it whole).
- POST is refused: boundaries are tied to a segment and its lane ranges, which ``ugvmap
  ingest lanes`` makes; a missing one is its ``offset`` row edited into place.

Same precondition, locking and history as segments and nodes (:mod:`app.network.editing`);
the change triggers of migration 0014 bump the network's version, so tiles and Lanelet2 maps
follow the edit.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.network import collections as colls
from app.network import crs as crs_
from app.network.editing import lock_feature, log_edit, unprocessable, write_change
from app.network.feature_bodies import patch_parts, whole_parts
from app.network.geometry_input import parse_geometry
from app.network.tokens import Principal

RESTATION = """
UPDATE lane_boundaries b
   SET station_from_m = LEAST(a, z) * s.length_m, station_to_m = GREATEST(a, z) * s.length_m,
       offset_m = NULL
  FROM road_segments s,
       LATERAL (SELECT ST_LineLocatePoint(s.geom, ST_StartPoint(b.geom)) AS a,
                       ST_LineLocatePoint(s.geom, ST_EndPoint(b.geom)) AS z) ends
 WHERE b.id = :id AND s.id = b.segment_id
"""


def _write(session: Session, c: colls.Collection, feature: dict[str, Any],
           new: dict[str, Any], raw_geometry: Any, crs: crs_.Crs, principal: Principal,
           action: str, conditional: bool) -> dict[str, Any]:
    moved = False
    if raw_geometry is not None:
        line, problem = parse_geometry(session, raw_geometry, "LineString", crs)
        if line is None:
            raise unprocessable({"geometry": problem or "is not valid"})
        moved = line != feature["geometry"]
        new["geometry"] = line
    written = write_change(session, c, feature, new, principal, action,
                           conditional=conditional)
    if moved:
        session.execute(text(RESTATION), {"id": feature["id"]})
        written = colls.get_item(session, c, feature["id"])
    return written


def patch_lane(session: Session, c: colls.Collection, fid: int, expected: int | None,
               body: Any, crs: crs_.Crs, principal: Principal) -> dict[str, Any]:
    """PATCH: a merge patch of the boundary's attributes and/or line."""
    properties, raw_geometry = patch_parts(body, "lanes")
    feature = lock_feature(session, c, fid, expected)
    return _write(session, c, feature, dict(properties), raw_geometry, crs, principal,
                  "update", expected is not None)


def replace_lane(session: Session, c: colls.Collection, fid: int, expected: int | None,
                 body: Any, crs: crs_.Crs, principal: Principal) -> dict[str, Any]:
    """PUT: the boundary's attributes replaced (defaults for those not given), its line set."""
    values, raw_geometry = whole_parts(body, "lanes")
    feature = lock_feature(session, c, fid, expected)
    return _write(session, c, feature, values, raw_geometry, crs, principal, "replace",
                  expected is not None)


def delete_lane(session: Session, c: colls.Collection, fid: int, expected: int | None,
                principal: Principal) -> None:
    """DELETE: the boundary goes; its history keeps it whole."""
    feature = lock_feature(session, c, fid, expected)
    session.execute(text("DELETE FROM lane_boundaries WHERE id = :id"), {"id": fid})
    log_edit(session, c, fid, "delete", feature["properties"]["version"], None, principal,
             {**feature["properties"], "geometry": feature["geometry"]}, None,
             conditional=expected is not None)
