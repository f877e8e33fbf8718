"""OSRM's documented response objects (osrm-backend ``docs/http.md``, v5) as JSON Schemas, so
tests check every answer of every service against the shape OSRM clients read.

Objects follow the document's sections: Waypoint (plus ``nodes`` on nearest, ``trips_index``
on trip, ``matchings_index`` / ``alternatives_count`` on match tracepoints), Route (plus
``confidence`` on matchings), RouteLeg, Annotation, RouteStep, StepManeuver, Intersection,
the table's matrices and the error object. Extra properties are allowed: ours (segment ids,
lanes, speed limits) come on top of OSRM's, never instead of them.
"""

from __future__ import annotations

from typing import Any

import jsonschema

NUMBER = {"type": "number"}
LONLAT = {"type": "array", "items": NUMBER, "minItems": 2, "maxItems": 2}
BEARING = {"type": "integer", "minimum": 0, "maximum": 360}
MANEUVER_TYPES = ["turn", "new name", "depart", "arrive", "merge", "ramp", "on ramp", "off ramp",
                  "fork", "end of road", "use lane", "continue", "roundabout", "rotary",
                  "roundabout turn", "notification", "exit roundabout", "exit rotary"]
MODIFIERS = ["uturn", "sharp right", "right", "slight right", "straight", "slight left", "left",
             "sharp left"]


def _object(required: dict[str, Any], optional: dict[str, Any] | None = None) -> dict:
    return {"type": "object", "required": list(required),
            "properties": {**required, **(optional or {})}}


def _list(items: dict) -> dict:
    return {"type": "array", "items": items}


WAYPOINT = _object({"name": {"type": "string"}, "location": LONLAT, "distance": NUMBER},
                   {"hint": {"type": "string"}})
GEOMETRY = {"oneOf": [{"type": "string"}, _object(
    {"type": {"const": "LineString"}, "coordinates": {**_list(LONLAT), "minItems": 2}})]}
MANEUVER = _object(
    {"location": LONLAT, "bearing_before": BEARING, "bearing_after": BEARING,
     "type": {"enum": MANEUVER_TYPES}},
    {"modifier": {"enum": MODIFIERS}, "exit": {"type": "integer", "minimum": 1}})
INTERSECTION = _object(
    {"location": LONLAT, "bearings": _list(BEARING), "entry": _list({"type": "boolean"})},
    {"in": {"type": "integer", "minimum": 0}, "out": {"type": "integer", "minimum": 0}})
STEP = _object(
    {"distance": NUMBER, "duration": NUMBER, "weight": NUMBER, "geometry": GEOMETRY,
     "name": {"type": "string"}, "mode": {"type": "string"}, "maneuver": MANEUVER,
     "intersections": {**_list(INTERSECTION), "minItems": 1},
     "driving_side": {"enum": ["left", "right"]}},
    {"ref": {"type": "string"}})
ANNOTATION = _object({}, {
    "distance": _list(NUMBER), "duration": _list(NUMBER), "speed": _list(NUMBER),
    "weight": _list(NUMBER), "nodes": _list({"type": "integer"}),
    "datasources": _list({"type": "integer"}),
    "metadata": _object({"datasource_names": _list({"type": "string"})})})
LEG = _object({"distance": NUMBER, "duration": NUMBER, "weight": NUMBER,
               "summary": {"type": "string"}, "steps": _list(STEP)},
              {"annotation": ANNOTATION})
ROUTE = _object({"distance": NUMBER, "duration": NUMBER, "weight": NUMBER,
                 "weight_name": {"type": "string"}, "legs": {**_list(LEG), "minItems": 1}},
                {"geometry": GEOMETRY})
MATRIX = _list(_list({"type": ["number", "null"]}))
INDEX = {"type": "integer", "minimum": 0}

SCHEMAS: dict[str, dict] = {
    "route": _object({"code": {"const": "Ok"}, "routes": {**_list(ROUTE), "minItems": 1}},
                     {"waypoints": _list(WAYPOINT)}),
    "nearest": _object({"code": {"const": "Ok"}, "waypoints": {**_list({"allOf": [
        WAYPOINT, _object({"nodes": {**_list({"type": "integer"}), "minItems": 2,
                                     "maxItems": 2}})]}), "minItems": 1}}),
    "table": _object({"code": {"const": "Ok"}}, {
        "durations": MATRIX, "distances": MATRIX, "sources": _list(WAYPOINT),
        "destinations": _list(WAYPOINT),
        "fallback_speed_cells": _list({**_list(INDEX), "minItems": 2, "maxItems": 2})}),
    "match": _object({"code": {"const": "Ok"}, "matchings": _list({"allOf": [ROUTE, _object(
        {"confidence": {"type": "number", "minimum": 0, "maximum": 1}})]})},
        {"tracepoints": _list({"oneOf": [{"type": "null"}, {"allOf": [WAYPOINT, _object({
            "matchings_index": INDEX, "waypoint_index": {"type": ["integer", "null"]},
            "alternatives_count": INDEX})]}]})}),
    "trip": _object({"code": {"const": "Ok"}, "trips": {**_list(ROUTE), "minItems": 1}},
                    {"waypoints": _list({"allOf": [WAYPOINT, _object(
                        {"trips_index": INDEX, "waypoint_index": INDEX})]})}),
    "error": _object({"code": {"type": "string", "minLength": 1},
                      "message": {"type": "string", "minLength": 1}}),
}


def check(body: dict, service: str) -> dict:
    """``body`` if it is a valid answer of ``service`` (or ``error``), else fail the test."""
    jsonschema.validate(body, SCHEMAS[service])
    return body
