"""Request bodies of edits: a JSON merge patch (PATCH) or a whole GeoJSON feature (POST
creates, PUT replaces), read the same way for segments and nodes.

- A merge patch names what changes: the properties alone (``{"lanes_forward": 2}``) or the
  feature (``{"properties": {..}, "geometry": {..}}``, what QGIS sends); a read-only or unknown
  property is a 422 naming it, ``null`` removes a nullable value (RFC 7396).
- A whole feature is the feature as a client holds it. QGIS sends every column it read,
  including those the server maintains (``segment_id``, ``version``, ``length_m``...) and,
  for a feature drawn in its form, ``null`` for every field left empty. So in a whole feature
  read-only properties are ignored (the server keeps its own), ``null`` or a missing editable
  property takes the column's default (PUT replaces the whole feature, RFC 9110), unknown
  properties are a 422, and the geometry is required.
- ``attrs`` (an object) may come as JSON text: OGR-based clients (QGIS, GDAL) hold object
  properties as a JSON string field and send them back that way. Numbers may come as number
  text (``"3.5"``) for the same reason: QGIS types a field String when the first page of
  items it typed the layer from had only nulls there (``width_m`` often does).
"""

from __future__ import annotations

import json
from typing import Any

from app.network import properties as props
from app.network.collections import Kind
from app.network.editing import unprocessable
from app.network.validation import DEFAULTS, DEPTH_PROBLEM, field_errors, numbers_from_text

FEATURE_KEYS = {"type", "id", "properties", "geometry", "links", "bbox"}


def read_only(kind: Kind) -> frozenset[str]:
    """The kind's properties the server maintains, plus ``id`` (never a property here)."""
    return frozenset({p.name for p in props.PROPERTIES[kind] if p.read_only} | {"id"})


def _from_text(properties: dict[str, Any], kind: Kind) -> dict[str, Any]:
    """What OGR-based clients send as text read as its value: ``attrs`` as JSON text, a
    segment's numbers as number text (:func:`~app.network.validation.numbers_from_text`)."""
    if kind == "segments":
        properties = numbers_from_text(properties)
    value = properties.get("attrs")
    if isinstance(value, str):
        try:
            parsed = json.loads(value)
        except ValueError:
            raise unprocessable({"attrs": "must be a JSON object (or its JSON text)"}) from None
        except RecursionError:  # deeper than the parser goes, so far deeper than the limit
            raise unprocessable({"attrs": DEPTH_PROBLEM}) from None
        return {**properties, "attrs": parsed}
    return properties


def _members(body: Any, whole: bool) -> tuple[dict[str, Any], Any]:
    if not isinstance(body, dict):
        raise unprocessable({"body": "must be a JSON object"})
    unknown = body.keys() - FEATURE_KEYS
    if unknown:
        raise unprocessable({k[:100]: "is not a feature member" for k in sorted(unknown)})
    if "type" in body and body["type"] != "Feature":
        raise unprocessable({"type": "must be Feature"})
    properties = body.get("properties") or {}
    if not isinstance(properties, dict):
        raise unprocessable({"properties": "must be a JSON object"})
    if whole and body.get("geometry") is None:
        raise unprocessable({"geometry": "is required"})
    return properties, body.get("geometry")


def patch_parts(body: Any, kind: Kind) -> tuple[dict[str, Any], Any]:
    """A merge patch -> (checked property patch, the raw new geometry or None)."""
    if isinstance(body, dict) and not body.keys() & {"properties", "geometry", "type"}:
        properties, geometry = body, None
    else:
        properties, geometry = _members(body, whole=False)
        if "geometry" in body and geometry is None:
            raise unprocessable({"geometry": "cannot be removed"})
    properties = _from_text(properties, kind)
    errors = field_errors(properties, kind, read_only(kind))
    if errors:
        raise unprocessable(errors)
    return properties, geometry


def whole_parts(body: Any, kind: Kind) -> tuple[dict[str, Any], Any]:
    """A whole feature -> (every editable property, defaults filled in; the raw geometry)."""
    properties, geometry = _members(body, whole=True)
    given = {k: v for k, v in _from_text(properties, kind).items()
             if k not in read_only(kind) and v is not None}
    errors = field_errors(given, kind)
    if errors:
        raise unprocessable(errors)
    return {**DEFAULTS[kind], **given}, geometry
