"""Turn input features (GeoJSON-like mappings, geo-interface objects) into RoadLines.

Properties named like our columns are taken as they are (our own exports round-trip);
OSM-style tags (``highway``, ``maxspeed``...) go through the OSM tag rules, SpaceNet labels
through the SpaceNet rules; anything else is kept in ``attrs``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from ingest.network.model import (
    ATTRIBUTE_NAMES,
    ONEWAY_VALUES,
    Coord,
    FeatureLike,
    RoadAttributes,
    RoadLine,
)
from ingest.network.osm_tags import attributes_from_tags
from ingest.network.spacenet_tags import attributes_from_spacenet, is_spacenet


def _as_int(value: Any, default: int) -> int:
    return default if value is None or value == "" else int(value)


def _as_float(value: Any) -> float | None:
    return None if value is None or value == "" else float(value)


def _as_share(value: Any) -> float | None:
    """A 0..1 share (``confidence``), refused outside that range rather than stored wrong."""
    share = _as_float(value)
    if share is not None and not 0.0 <= share <= 1.0:
        raise ValueError(f"confidence must be a number from 0 to 1, got {value!r}")
    return share


def _as_text(value: Any) -> str | None:
    return None if value is None else str(value)


def as_bool(value: Any) -> bool:
    """A flag from a file: GeoPackage and GeoJSON write booleans as bools, ints or strings."""
    if isinstance(value, str):
        return value.strip().lower() in ("1", "true", "yes", "t")
    return bool(value)


def _as_attrs(value: Any) -> dict[str, Any]:
    if value is None or value == "":
        return {}
    if isinstance(value, str):
        value = json.loads(value)
    if not isinstance(value, Mapping):
        raise ValueError("attrs must be a JSON object")
    return dict(value)


def attributes_from_properties(props: Mapping[str, Any]) -> RoadAttributes:
    """Map a feature's properties onto the segment columns.

    Properties named like our columns are used as they are (that is what our own exports
    write, so export/import round-trips); ``attrs`` may be an object or a JSON string (GeoPackage
    has no object type). Every other property is kept in ``attrs`` so nothing is lost.
    """
    if "highway" in props and not any(k in props for k in ("road_class", "oneway")):
        tags = {k: str(v) for k, v in props.items() if v is not None}
        return attributes_from_tags(tags)
    if is_spacenet(props) and "road_class" not in props:
        return attributes_from_spacenet(props)
    oneway = props.get("oneway") or "none"
    if oneway not in ONEWAY_VALUES:
        raise ValueError(f"oneway must be one of {', '.join(ONEWAY_VALUES)}, got {oneway!r}")
    attrs = _as_attrs(props.get("attrs"))
    derived = {"id", "source_node", "target_node", "length_m", "version", "updated_at",
               "updated_by", "attrs", "feature_type"}
    for key, value in props.items():
        if key not in ATTRIBUTE_NAMES and key not in derived and value is not None:
            attrs.setdefault(key, value)
    return RoadAttributes(
        lanes_forward=_as_int(props.get("lanes_forward"), 1),
        lanes_backward=_as_int(props.get("lanes_backward"), 1),
        speed_limit_kph=_as_float(props.get("speed_limit_kph")),
        oneway=oneway,
        road_class=_as_text(props.get("road_class")) or "unclassified",
        is_junction=as_bool(props.get("is_junction")),
        name=_as_text(props.get("name")),
        surface=_as_text(props.get("surface")),
        width_m=_as_float(props.get("width_m")),
        external_id=_as_text(props.get("external_id")),
        attrs=attrs,
        confidence=_as_share(props.get("confidence")),
    )


def _line_parts(geometry: Mapping[str, Any]) -> list[list[Coord]]:
    kind = geometry.get("type")
    coords = geometry.get("coordinates") or []
    if kind == "LineString":
        return [[(float(c[0]), float(c[1])) for c in coords]]
    if kind == "MultiLineString":
        return [[(float(c[0]), float(c[1])) for c in part] for part in coords]
    raise ValueError(f"expected a LineString or MultiLineString, got {kind}")


def as_road_lines(feature: FeatureLike) -> list[RoadLine]:
    """Normalise one input feature (RoadLine, GeoJSON mapping, or geo-interface) to RoadLines.

    A MultiLineString becomes one RoadLine per part with the same attributes.
    """
    if isinstance(feature, RoadLine):
        return [feature]
    mapping = feature if isinstance(feature, Mapping) else feature.__geo_interface__
    if mapping.get("type") == "Feature":
        geometry, props = mapping.get("geometry") or {}, mapping.get("properties") or {}
    else:
        geometry, props = mapping, {}
    attributes = attributes_from_properties(props)
    return [RoadLine(part, attributes) for part in _line_parts(geometry)]
