"""Shape legs into an OSRM route-service response, so existing OSRM clients work unchanged.

Follows OSRM v5 (``code``, ``routes[].geometry|distance|duration|weight|legs[].steps[]``,
``waypoints[]``), with per-step extensions a vehicle planner needs: ``segment_id``,
``lanes`` (in the direction of travel), ``speed_limit_kph``, ``speed_kph`` and ``road_class``.
Maneuver modifiers are ``straight``, ``left``, ``right`` and ``uturn``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import polyline

from app.routing.costs import Cost
from app.routing.engine import Leg, Piece
from app.routing.geometry import bearing, cut, point_at
from app.routing.graph import RoadGraph

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
    if geometries == "polyline":
        return polyline.encode([(lat, lon) for lon, lat in coords], 5)
    return {"type": "LineString", "coordinates": coords}


def _end_bearings(coords: list[list[float]]) -> tuple[float, float]:
    """Bearing leaving the first point and bearing arriving at the last."""
    return bearing(coords[0], coords[1]), bearing(coords[-2], coords[-1])


class Shaper:
    """Turns the legs of one request into the response dictionary."""

    def __init__(self, graph: RoadGraph, geometries: str) -> None:
        self.graph, self.geometries = graph, geometries

    def piece_coords(self, p: Piece) -> list[list[float]]:
        coords, fracs = self.graph.line(p.row)
        return cut(coords, fracs, p.f_from, p.f_to)

    def location(self, segment_id: int, fraction: float) -> list[float]:
        row = self.graph.row_of(segment_id)
        coords, fracs = self.graph.line(row)
        return list(point_at(coords, fracs, fraction))

    def step(self, p: Piece, coords: list[list[float]], maneuver: dict) -> dict[str, Any]:
        s, g = self.graph.segs, self.graph
        span = abs(p.f_to - p.f_from)
        forward = p.f_to >= p.f_from
        limit = s.speed_limit[p.row]
        return {
            "distance": span * float(s.length_m[p.row]),
            "duration": span * float(s.length_m[p.row]) / (float(g.speed_kph[p.row]) / 3.6),
            "geometry": encode(coords, self.geometries),
            "name": s.name[p.row] or "",
            "mode": "driving",
            "maneuver": maneuver,
            "segment_id": int(s.ids[p.row]),
            "lanes": int(s.lanes_forward[p.row] if forward else s.lanes_backward[p.row]),
            "speed_limit_kph": None if limit != limit else float(limit),
            "speed_kph": float(g.speed_kph[p.row]),
            "road_class": s.road_class[p.row],
        }

    def leg(self, leg: Leg, heading_in: float | None) -> tuple[dict[str, Any], list, float | None]:
        """The leg's dict, its coordinates, and the bearing it arrives with."""
        pieces = [p for p in leg.pieces if p.f_from != p.f_to]
        start = self.location(leg.start.segment_id, leg.start.fraction)
        end = self.location(leg.end.segment_id, leg.end.fraction)
        steps, coords = [], [start]
        for k, p in enumerate(pieces):
            pc = self.piece_coords(p)
            b_after, b_in = _end_bearings(pc)
            before = heading_in if heading_in is not None else b_after
            maneuver = {"type": "depart" if k == 0 else "turn", "location": pc[0],
                        "bearing_before": round(before), "bearing_after": round(b_after),
                        "modifier": modifier(before, b_after)}
            if maneuver["modifier"] == "straight" and k:
                maneuver["type"] = "continue"
            steps.append(self.step(p, pc, maneuver))
            coords.extend(pc[1:])
            heading_in = b_in
        arrive = {"type": "arrive", "location": end, "bearing_before": round(heading_in or 0),
                  "bearing_after": 0, "modifier": "straight"}
        steps.append({"distance": 0.0, "duration": 0.0, "geometry": encode([end, end],
                      self.geometries), "name": "", "mode": "driving", "maneuver": arrive})
        distance = sum(st["distance"] for st in steps)
        duration = sum(st["duration"] for st in steps)
        return ({"distance": distance, "duration": duration, "weight": leg.weight,
                 "summary": "", "steps": steps}, coords, heading_in)

    def waypoint(self, snap: Any, extra: dict | None = None) -> dict[str, Any]:
        row = self.graph.row_of(snap.segment_id)
        return {"name": self.graph.segs.name[row] or "",
                "location": self.location(snap.segment_id, snap.fraction),
                "distance": snap.distance_m, "segment_id": snap.segment_id,
                "fraction": snap.fraction, **(extra or {})}

    def response(self, legs: Sequence[Leg], cost: Cost, snaps: Sequence[Any],
                 order: Sequence[int] | None = None) -> dict[str, Any]:
        heading, legs_out, coords = None, [], []
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
                "waypoints": [self.waypoint(s, {"waypoint_index": rank[s.index]})
                              for s in snaps]}
