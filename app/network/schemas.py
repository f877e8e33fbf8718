"""Schemas of a collection's features, each in the shape one kind of client reads, all built
from :mod:`app.network.properties`:

- ``queryables`` (OGC API Features Part 3): the properties ``?name=value`` filters by;
- ``schema`` (Part 5, as QGIS reads it): the properties flat, with the id and the geometry
  marked by ``x-ogc-role``;
- the GeoJSON Feature schema behind the ``describedby`` link (what GDAL's OAPIF driver reads);
- OpenAPI 3.0 schemas of items and pages for the API document, strict enough that a
  property of the wrong type fails the schemathesis run.
"""

from __future__ import annotations

from typing import Any

from app.network import validation as v
from app.network.collections import Kind
from app.network.properties import GEOMETRY, PROPERTIES, queryables

JSON_SCHEMA = "https://json-schema.org/draft/2020-12/schema"
SCHEMA_JSON = "application/schema+json"


def _geometry(kind: Kind) -> dict[str, Any]:
    position = {"type": "array", "minItems": 2, "items": {"type": "number"}}
    coordinates = position if kind == "nodes" else {"type": "array", "minItems": 2,
                                                    "items": position}
    return {"type": "object", "required": ["type", "coordinates"],
            "properties": {"type": {"type": "string", "enum": [GEOMETRY[kind]]},
                           "coordinates": coordinates}}


def queryables_document(kind: Kind, url: str, title: str) -> dict[str, Any]:
    """Part 3 queryables: a JSON Schema of the properties the items endpoint filters by."""
    return {"$schema": JSON_SCHEMA, "$id": url, "type": "object", "title": title,
            "properties": {p.name: p.json_schema() for p in queryables(kind)},
            "additionalProperties": False}


def part5_document(kind: Kind, url: str, title: str) -> dict[str, Any]:
    """Part 5 (draft) schema: every property in item order, read-only ones marked, plus the
    feature id and the primary geometry by role."""
    properties: dict[str, Any] = {
        "id": {"type": "integer", "title": "id", "x-ogc-role": "id", "readOnly": True},
        "geometry": {"title": "geometry", "x-ogc-role": "primary-geometry",
                     "format": f"geometry-{GEOMETRY[kind].lower()}"},
    }
    for seq, prop in enumerate(PROPERTIES[kind], start=1):
        properties[prop.name] = {**prop.json_schema(), "readOnly": prop.read_only,
                                 "x-ogc-propertySeq": seq}
    return {"$schema": JSON_SCHEMA, "$id": url, "type": "object", "title": title,
            "properties": properties}


def geojson_feature_document(kind: Kind, url: str, title: str) -> dict[str, Any]:
    """The ``describedby`` schema: a GeoJSON Feature whose ``properties`` are typed."""
    return {"$schema": JSON_SCHEMA, "$id": url, "title": title, "type": "object",
            "required": ["type", "id", "geometry", "properties"],
            "properties": {
                "type": {"type": "string", "enum": ["Feature"]},
                "id": {"type": "integer"},
                "geometry": _geometry(kind),
                "properties": {"type": "object",
                               "properties": {p.name: p.json_schema()
                                              for p in PROPERTIES[kind]}},
            }}


def openapi_feature(kind: Kind | None) -> dict[str, Any]:
    """OpenAPI 3.0 schema of one item of a kind (every property always present, null when
    unknown), or of any item with ``None``."""
    if kind is None:
        geometry: dict[str, Any] = {"type": "object"}
        attributes: dict[str, Any] = {"type": "object"}
    else:
        geometry = _geometry(kind)
        attributes = {"type": "object", "required": [p.name for p in PROPERTIES[kind]],
                      "properties": {p.name: p.openapi_schema() for p in PROPERTIES[kind]}}
    return {"type": "object", "required": ["type", "id", "geometry", "properties"],
            "properties": {
                "type": {"type": "string", "enum": ["Feature"]},
                "id": {"type": "integer"},
                "geometry": geometry,
                "properties": attributes,
                "links": {"type": "array", "items": {"$ref": "#/components/schemas/Link"}},
            }}


def openapi_feature_collection(item: str) -> dict[str, Any]:
    """OpenAPI 3.0 schema of one page of items, each of the component schema ``item``."""
    return {"type": "object",
            "required": ["type", "features", "numberMatched", "numberReturned", "links"],
            "properties": {
                "type": {"type": "string", "enum": ["FeatureCollection"]},
                "features": {"type": "array",
                             "items": {"$ref": f"#/components/schemas/{item}"}},
                "numberMatched": {"type": "integer", "minimum": 0},
                "numberReturned": {"type": "integer", "minimum": 0},
                "timeStamp": {"type": "string", "format": "date-time"},
                "links": {"type": "array", "items": {"$ref": "#/components/schemas/Link"}},
            }}


def _editable_schema(kind: Kind) -> dict[str, Any]:
    """What a merge patch of a kind may set, with the editing rules as schema constraints
    (``null`` removes a nullable value, as RFC 7396 says)."""
    limits: dict[str, dict[str, Any]] = {
        "lanes_forward": {"minimum": 0, "maximum": v.MAX_LANES},
        "lanes_backward": {"minimum": 0, "maximum": v.MAX_LANES},
        "speed_limit_kph": {"minimum": v.SPEED_RANGE[0], "maximum": v.SPEED_RANGE[1]},
        "width_m": {"minimum": v.WIDTH_RANGE[0], "maximum": v.WIDTH_RANGE[1]},
        "road_class": {"enum": list(v.ROAD_CLASSES)},
        "name": {"maxLength": v.MAX_NAME},
        "surface": {"maxLength": v.MAX_SHORT_TEXT},
        "external_id": {"maxLength": v.MAX_NAME},
    }
    if kind == "lanes":  # a painted line's width, not a carriageway's
        limits = {"width_m": {"minimum": v.LANE_LINE_WIDTH_RANGE[0],
                              "maximum": v.LANE_LINE_WIDTH_RANGE[1]},
                  "position": {"minimum": 0, "maximum": v.MAX_LANE_POSITION}}
    return {"type": "object", "additionalProperties": False, "minProperties": 1,
            "properties": {p.name: {**p.openapi_schema(), **limits.get(p.name, {})}
                           for p in PROPERTIES[kind] if not p.read_only}}


def openapi_patch_body() -> dict[str, Any]:
    """The PATCH body: a merge patch of a segment's, a node's or a lane boundary's properties,
    or of the feature (properties and a new geometry: a segment's keeps its end nodes, a
    node's moves it)."""
    options: list[dict[str, Any]] = []
    for kind in ("segments", "nodes", "lanes"):
        editable = _editable_schema(kind)
        options += [editable, {
            "type": "object", "minProperties": 1,
            "properties": {"type": {"type": "string", "enum": ["Feature"]},
                           "properties": editable,
                           "geometry": _geometry(kind)}}]
    return {"anyOf": options}


def openapi_feature_input() -> dict[str, Any]:
    """A whole feature sent to POST (create) or PUT (replace): its geometry is required, its
    properties are those a client holds (server-kept ones are ignored)."""
    return {"type": "object", "required": ["type", "geometry"],
            "properties": {"type": {"type": "string", "enum": ["Feature"]},
                           "geometry": {"type": "object"},
                           "properties": {"type": "object", "nullable": True}}}


SPLIT_BODY: dict[str, Any] = {"oneOf": [
    {"type": "object", "required": ["fraction"], "additionalProperties": False,
     "properties": {"fraction": {"type": "number", "minimum": 0, "maximum": 1,
                                 "exclusiveMinimum": True, "exclusiveMaximum": True}}},
    {"type": "object", "required": ["point"], "additionalProperties": False,
     "properties": {"point": {"type": "array", "minItems": 2, "maxItems": 2,
                              "items": {"type": "number"}, "description": "[lon, lat]"}}},
]}
MERGE_BODY: dict[str, Any] = {
    "type": "object", "required": ["segments"], "additionalProperties": False,
    "properties": {"segments": {"type": "array", "minItems": 2, "maxItems": 2,
                                "items": {"type": "integer", "minimum": 1},
                                "description": "The two segment ids; the first is kept"}}}
HISTORY: dict[str, Any] = {
    "type": "object", "required": ["id", "edits"],
    "properties": {"id": {"type": "integer"}, "edits": {"type": "array", "items": {
        "type": "object",
        "properties": {"action": {"type": "string"},
                       "version_from": {"type": "integer", "nullable": True},
                       "version_to": {"type": "integer", "nullable": True},
                       "edited_by": {"type": "string"},
                       "edited_at": {"type": "string", "format": "date-time"},
                       "conditional": {"type": "boolean"},
                       "old": {"type": "object", "nullable": True},
                       "new": {"type": "object", "nullable": True}}}}}}
SPLIT_ANSWER: dict[str, Any] = {
    "type": "object", "required": ["type", "features"],
    "description": "The two segments the split made (not a page of items: no numberMatched)",
    "properties": {"type": {"type": "string", "enum": ["FeatureCollection"]},
                   "features": {"type": "array", "minItems": 2, "maxItems": 2,
                                "items": {"$ref": "#/components/schemas/Feature"}}}}
