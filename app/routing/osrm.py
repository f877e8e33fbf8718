"""Shape legs into an OSRM route-service response, so existing OSRM clients work unchanged.

Follows OSRM v5 (``code``, ``routes[].geometry|distance|duration|weight|legs[].steps[]``,
``waypoints[]``). A step is a stretch driven without a turn on segments with the same name,
class, lanes and speed limit, and carries what a vehicle planner needs besides OSRM's fields:
``segment_ids``, ``lanes`` (in the direction of travel), ``speed_limit_kph``, ``speed_kph``
and ``road_class``. Maneuver modifiers are ``straight``, ``left``, ``right`` and ``uturn``.
Each leg's ``annotation`` lists every segment piece driven: ``segment_ids``, ``forward``
(along the segment's geometry or against it), ``distance`` (m) and ``duration`` (s).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import polyline

from app.routing.costs import Cost
from app.routing.engine import Leg, Piece
from app.routing.geometry import bearing, cut, point_at
from app.routing.graph import RoadGraph
from app.routing.snap import Snap

STRAIGHT_DEG = 30.0
UTURN_DEG = 150.0


def modifier(before: float, after: float) -> str:
    """Turn direction from the bearing before to the bearing after a maneuver point."""
    delta = (after - before + 540.0) % 360.0 - 180.0  # -180..180, positive = clockwise
    if abs(delta) <= STRAIGHT_DEG:
        return "straight"
    if abs(delta) >= UTURN_DEG:
        return "uturn"
    return "right" if delta > 0 else "left"


def encode(coords: list[list[float]], geometries: str) -> Any:
    """The geometry as OSRM sends it: an encoded polyline (precision 5) or GeoJSON."""
    if geometries == "polyline":
        return polyline.encode([(lat, lon) for lon, lat in coords], 5)
    return {"type": "LineString", "coordinates": coords}


class Shaper:
    """Turns the legs of one request into the response dictionary."""

    def __init__(self, graph: RoadGraph, geometries: str) -> None:
        self.graph, self.geometries = graph, geometries

    def piece_coords(self, p: Piece) -> list[list[float]]:
        """Coordinates of the driven part of a segment, in driving direction."""
        coords, fracs = self.graph.line(p.row)
        return cut(coords, fracs, p.f_from, p.f_to)

    def location(self, snap: Snap) -> list[float]:
        """Where a snapped point lies on its segment (lon, lat)."""
        row = self.graph.row_of(snap.segment_id)
        assert row is not None  # the route was planned on this graph, so it holds the snaps
        coords, fracs = self.graph.line(row)
        return list(point_at(coords, fracs, snap.fraction))

    def _bearings(self, p: Piece, pc: list[list[float]]) -> tuple[float, float]:
        """Bearing leaving and bearing arriving, precomputed for whole segments."""
        g = self.graph
        if (p.f_from, p.f_to) == (0.0, 1.0):
            return float(g.bearing_start[p.row]), float(g.bearing_end[p.row])
        if (p.f_from, p.f_to) == (1.0, 0.0):
            return ((float(g.bearing_end[p.row]) + 180.0) % 360.0,
                    (float(g.bearing_start[p.row]) + 180.0) % 360.0)
        return bearing(pc[0], pc[1]), bearing(pc[-2], pc[-1])

    def _attrs(self, p: Piece) -> dict[str, Any]:
        """Per-step attributes of a piece: a new step starts where any of them changes."""
        s, row = self.graph.segs, p.row
        limit = s.speed_limit[row]
        return {
            "name": s.name[row] or "",
            "lanes": int(s.lanes_forward[row] if p.f_to >= p.f_from else s.lanes_backward[row]),
            "speed_limit_kph": None if limit != limit else float(limit),
            "speed_kph": float(self.graph.speed_kph[row]),
            "road_class": s.road_class[row],
        }

    def leg(self, leg: Leg, heading_in: float | None) -> tuple[dict[str, Any], list, float | None]:
        """The leg's dict, its coordinates, and the bearing it arrives with."""
        s, g = self.graph.segs, self.graph
        steps: list[dict[str, Any]] = []
        coords = [self.location(leg.start)]
        note: dict[str, list] = {"segment_ids": [], "forward": [], "distance": [], "duration": []}
        for p in (p for p in leg.pieces if p.f_from != p.f_to):
            pc = self.piece_coords(p)
            b_out, b_in = self._bearings(p, pc)
            span = abs(p.f_to - p.f_from)
            dist = span * float(s.length_m[p.row])
            dur = dist / (float(g.speed_kph[p.row]) / 3.6)
            attrs = self._attrs(p)
            turn = modifier(heading_in if heading_in is not None else b_out, b_out)
            if steps and turn == "straight" and steps[-1]["_attrs"] == attrs:
                step = steps[-1]
                step["distance"] += dist
                step["duration"] += dur
                step["_coords"].extend(pc[1:])
                step["segment_ids"].append(int(s.ids[p.row]))
            else:
                before = heading_in if heading_in is not None else b_out
                kind = "depart" if not steps else "continue" if turn == "straight" else "turn"
                steps.append({
                    "distance": dist, "duration": dur, "_coords": pc, "_attrs": attrs,
                    "mode": "driving",
                    "maneuver": {"type": kind, "location": pc[0], "modifier": turn,
                                 "bearing_before": round(before), "bearing_after": round(b_out)},
                    "segment_ids": [int(s.ids[p.row])], **attrs,
                })
            for key, value in (("segment_ids", int(s.ids[p.row])),
                               ("forward", p.f_to >= p.f_from), ("distance", dist),
                               ("duration", dur)):
                note[key].append(value)
            coords.extend(pc[1:])
            heading_in = b_in
        end = self.location(leg.end)
        for step in steps:
            step["geometry"] = encode(step.pop("_coords"), self.geometries)
            del step["_attrs"]
        steps.append({
            "distance": 0.0, "duration": 0.0, "geometry": encode([end, end], self.geometries),
            "name": "", "mode": "driving", "segment_ids": [],
            "maneuver": {"type": "arrive", "location": end, "modifier": "straight",
                         "bearing_before": round(heading_in or 0), "bearing_after": 0},
        })
        out = {"distance": sum(note["distance"]), "duration": sum(note["duration"]),
               "weight": leg.weight, "summary": "", "steps": steps, "annotation": note}
        return out, coords, heading_in

    def waypoint(self, snap: Snap, waypoint_index: int) -> dict[str, Any]:
        """An OSRM waypoint, plus the segment id and fraction the point snapped to."""
        row = self.graph.row_of(snap.segment_id)
        return {"name": self.graph.segs.name[row] or "", "location": self.location(snap),
                "distance": snap.distance_m, "segment_id": snap.segment_id,
                "fraction": snap.fraction, "waypoint_index": waypoint_index}

    def response(self, legs: Sequence[Leg], cost: Cost, snaps: Sequence[Snap],
                 order: Sequence[int] | None = None) -> dict[str, Any]:
        """The whole OSRM route-service response for the legs."""
        heading: float | None = None
        legs_out: list[dict[str, Any]] = []
        coords: list[list[float]] = []
        for leg in legs:
            out, leg_coords, heading = self.leg(leg, heading)
            legs_out.append(out)
            coords.extend(leg_coords if not coords else leg_coords[1:])
        if len(coords) == 1:
            coords.append(coords[0])
        visit = list(order) if order is not None else list(range(len(snaps)))
        rank = {i: k for k, i in enumerate(visit)}
        route = {
            "geometry": encode(coords, self.geometries),
            "distance": sum(leg["distance"] for leg in legs_out),
            "duration": sum(leg["duration"] for leg in legs_out),
            "weight": sum(leg.weight for leg in legs),
            "weight_name": "duration" if cost is Cost.TIME else "distance",
            "legs": legs_out,
        }
        return {"code": "Ok", "routes": [route],
                "waypoints": [self.waypoint(s, rank[s.index]) for s in snaps]}
