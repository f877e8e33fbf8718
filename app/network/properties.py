"""The feature properties of each collection kind, with their types: one table, read by every
place that describes them to a client.

Clients guess attribute types from sample values when nobody tells them (a page whose first
``width_m`` is null makes GDAL and QGIS type it String), so the OGC schema, the queryables,
the OpenAPI response schemas, the simple property filters of the items endpoint and the
TileJSON field list are all generated from :data:`PROPERTIES` and cannot disagree.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Literal

from app.db.models import LANE_COLOURS, LANE_KINDS, LANE_SOURCES, NODE_KINDS, ONEWAY_VALUES
from app.errors import InvalidParameterValueError
from app.network.collections import Kind
from app.network.validation import text_problem

JsonType = Literal["integer", "number", "string", "boolean", "object"]
# Vector tile field types as Mapbox's TileJSON and GDAL's MVT driver spell them.
MVT_TYPES: dict[str, str] = {"integer": "Number", "number": "Number", "string": "String",
                             "boolean": "Boolean", "object": "String"}
MAX_FILTER_TEXT = 200


@dataclass(frozen=True)
class Property:
    """One feature property: its JSON type, whether it may be null, what it means, and
    whether ``?name=value`` on the items endpoint filters by it (a queryable)."""

    name: str
    type: JsonType
    description: str
    nullable: bool = False
    queryable: bool = False
    read_only: bool = True
    enum: tuple[str, ...] | None = None
    format: str | None = None

    def json_schema(self) -> dict[str, Any]:
        """The property as a JSON Schema (a single ``type`` string: GDAL and QGIS read only
        that form; a null value means unknown)."""
        schema: dict[str, Any] = {"type": self.type, "title": self.name,
                                  "description": self.description}
        if self.enum:
            schema["enum"] = list(self.enum)
        if self.format:
            schema["format"] = self.format
        return schema

    def openapi_schema(self) -> dict[str, Any]:
        """The property as an OpenAPI 3.0 schema, where null is said with ``nullable``."""
        schema = {k: v for k, v in self.json_schema().items() if k != "title"}
        if self.nullable:
            schema["nullable"] = True
        return schema

    def parse_filter(self, raw: str) -> Any:
        """A ``?name=value`` filter value as the column's type; 400 when it cannot be one."""
        if self.type == "integer":
            if not re.fullmatch(r"-?[0-9]{1,18}", raw):
                raise InvalidParameterValueError(f"{self.name} must be an integer")
            return int(raw)
        if self.type == "number":
            try:
                number = float(raw)
            except ValueError:
                number = math.nan
            if not math.isfinite(number):
                raise InvalidParameterValueError(f"{self.name} must be a number")
            return number
        if self.type == "boolean":
            if raw not in ("true", "false"):
                raise InvalidParameterValueError(f"{self.name} must be true or false")
            return raw == "true"
        problem = text_problem(raw, MAX_FILTER_TEXT)
        if problem:
            raise InvalidParameterValueError(f"{self.name} {problem}")
        return raw


def _editable(name: str, type_: JsonType, description: str, **kw: Any) -> Property:
    return Property(name, type_, description, read_only=False, **kw)


PROPERTIES: dict[Kind, tuple[Property, ...]] = {
    "segments": (
        Property("segment_id", "integer", "The segment's id (the feature id, repeated as a "
                 "property: clients reading GeoJSON through OGR show no feature id)"),
        Property("source_node", "integer", "Node the segment starts at (its geometry's "
                 "first point)", queryable=True),
        Property("target_node", "integer", "Node the segment ends at", queryable=True),
        Property("length_m", "number", "Length along the ground (geography), metres"),
        Property("version", "integer", "Edit version; the item's ETag"),
        Property("updated_at", "string", "When the segment last changed", format="date-time"),
        Property("updated_by", "string", "Who changed it last", nullable=True),
        Property("confidence", "number", "How sure road extraction was of the segment, 0..1 "
                 "(e.g. the mean road probability along it); null when it was not extracted "
                 "from imagery. Set by extraction only; a human edit keeps it (the history "
                 "says who reviewed the segment)", nullable=True, queryable=True),
        _editable("lanes_forward", "integer", "Lanes in the direction of the geometry",
                  queryable=True),
        _editable("lanes_backward", "integer", "Lanes against the direction of the geometry",
                  queryable=True),
        _editable("speed_limit_kph", "number", "Speed limit, km/h", nullable=True,
                  queryable=True),
        _editable("oneway", "string", "Allowed direction of travel", enum=ONEWAY_VALUES,
                  queryable=True),
        _editable("road_class", "string", "Road class (OSM highway values)", queryable=True),
        _editable("is_junction", "boolean", "Part of a junction (e.g. a roundabout)",
                  queryable=True),
        _editable("name", "string", "Street name", nullable=True, queryable=True),
        _editable("surface", "string", "Surface (OSM surface values)", nullable=True,
                  queryable=True),
        _editable("width_m", "number", "Carriageway width, metres", nullable=True),
        _editable("external_id", "string", "Id in the source data (e.g. OSM way id)",
                  nullable=True, queryable=True),
        _editable("attrs", "object", "Other source attributes"),
    ),
    "nodes": (
        Property("node_id", "integer", "The node's id (the feature id, repeated as a "
                 "property: clients reading GeoJSON through OGR show no feature id)"),
        Property("kind", "string", "junction (3+ segments), endpoint (1) or node (2)",
                 enum=NODE_KINDS, queryable=True),
        _editable("traffic_light", "boolean", "Traffic signals at the node", queryable=True),
        _editable("external_id", "string", "Id in the source data (e.g. OSM node id)",
                  nullable=True, queryable=True),
        Property("version", "integer", "Edit version; the item's ETag"),
        Property("updated_at", "string", "When the node last changed", format="date-time"),
        Property("updated_by", "string", "Who changed it last", nullable=True),
        Property("degree", "integer", "Number of segment ends at the node"),
    ),
    "lanes": (
        Property("boundary_id", "integer", "The boundary's id (the feature id, repeated as a "
                 "property: clients reading GeoJSON through OGR show no feature id)"),
        Property("segment_id", "integer", "The segment whose road the line bounds lanes of",
                 queryable=True),
        _editable("kind", "string", "What is painted: solid, dashed, solid_solid, road_edge, "
                  "stop_line (across the lanes), crosswalk (a zebra crossing: the line across "
                  "the road through its bars, width_m its reach along the road) or other",
                  enum=LANE_KINDS, queryable=True),
        _editable("colour", "string", "Colour of the paint", enum=LANE_COLOURS,
                  queryable=True),
        _editable("width_m", "number", "Width of the painted line, metres", nullable=True),
        Property("confidence", "number", "How sure extraction was of the line, 0..1 (0 for "
                 "an offset line: no paint there)", nullable=True),
        _editable("position", "integer", "Order across the road within its lane range, 0 = "
                  "the rightmost boundary along the segment's direction; null for stop lines "
                  "and symbols", nullable=True, queryable=True),
        Property("offset_m", "number", "Median offset from the segment's centreline, metres, "
                 "+ left of its direction", nullable=True),
        Property("station_from_m", "number", "Where along the segment it starts, metres from "
                 "the segment's start"),
        Property("station_to_m", "number", "Where along the segment it ends"),
        _editable("source", "string", "paint (found in the imagery, or drawn over it by a "
                  "person) or offset (no paint there: the lane range's offset along the "
                  "segment, a guess)", enum=LANE_SOURCES, queryable=True),
        Property("version", "integer", "Edit version; the item's ETag"),
        Property("updated_at", "string", "When the boundary last changed", format="date-time"),
        Property("updated_by", "string", "Who changed it last (ingest-lanes when extracted)",
                 nullable=True),
        Property("lanes_forward", "integer", "Lanes along the segment's direction where the "
                 "boundary lies (its lane range)", nullable=True),
        Property("lanes_backward", "integer", "Lanes against it there", nullable=True),
        Property("lane_widths_m", "string", "Widths of those lanes, metres, right to left "
                 "across the road along the segment's direction (comma-separated)",
                 nullable=True),
    ),
}
GEOMETRY: dict[Kind, str] = {"segments": "LineString", "nodes": "Point",
                             "lanes": "LineString"}


def by_name(kind: Kind) -> dict[str, Property]:
    """The kind's properties keyed by name."""
    return {p.name: p for p in PROPERTIES[kind]}


def queryables(kind: Kind) -> tuple[Property, ...]:
    """The properties a ``?name=value`` items filter accepts."""
    return tuple(p for p in PROPERTIES[kind] if p.queryable)
