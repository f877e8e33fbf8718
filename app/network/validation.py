"""Field rules for segment edits: every bad field gets its own message (422), nothing is
half-applied. Pure functions, so the rules are tested without HTTP.

Strings are checked for what PostgreSQL would otherwise reject with a server error (NUL
characters, unpaired surrogates), so hostile input is refused cleanly, never half-stored.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable
from typing import Any

from app.db.models import LANE_COLOURS, LANE_KINDS, LANE_SOURCES, ONEWAY_VALUES
from app.network.collections import LANE_ATTRIBUTES, NODE_ATTRIBUTES, SEGMENT_ATTRIBUTES, Kind

ROAD_CLASSES = (
    "motorway", "motorway_link", "trunk", "trunk_link", "primary", "primary_link",
    "secondary", "secondary_link", "tertiary", "tertiary_link", "unclassified", "residential",
    "living_street", "service", "road", "track", "pedestrian", "busway", "bus_guideway",
    "footway", "cycleway", "bridleway", "path", "steps", "corridor", "escape", "raceway",
)
MAX_LANES = 8
SPEED_RANGE = (5.0, 150.0)
WIDTH_RANGE = (0.5, 100.0)
MAX_NAME = 200
MAX_SHORT_TEXT = 64
MAX_ATTRS_BYTES = 16_384
MAX_ATTRS_DEPTH = 32
"""How deeply ``attrs`` may nest (objects and arrays). Why a limit: a value must come back
out of every reader of the network (the history and item reads, exports, tiles), and
serializers give up on deep values (pydantic at 255, Python's at ~1000 levels) while
PostgreSQL stores them; source attributes (OSM tags) are flat."""
DEPTH_PROBLEM = f"must be nested at most {MAX_ATTRS_DEPTH} levels deep"
NULLABLE = {"speed_limit_kph", "name", "surface", "width_m", "external_id", "attrs", "position"}
# What a whole feature (POST, PUT) gets for an editable attribute it does not give: the
# columns' defaults, so a road drawn in QGIS with its form left empty is a plain two-way road.
DEFAULTS: dict[Kind, dict[str, Any]] = {
    "segments": {"lanes_forward": 1, "lanes_backward": 1, "speed_limit_kph": None,
                 "oneway": "none", "road_class": "unclassified", "is_junction": False,
                 "name": None, "surface": None, "width_m": None, "external_id": None,
                 "attrs": {}},
    "nodes": {"traffic_light": False, "external_id": None},
    "lanes": {"kind": "solid", "colour": "unknown", "width_m": None, "position": None,
              "source": "paint"},
}


def text_problem(value: str, limit: int) -> str | None:
    """Why a text value cannot be stored (too long, NUL, unencodable), or None."""
    if len(value) > limit:
        return f"must be at most {limit} characters"
    if "\x00" in value:
        return "must not contain NUL characters"
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        return "must be valid Unicode text"
    return None


def _int_in(low: int, high: int) -> Callable[[Any], str | None]:
    def check(value: Any) -> str | None:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            return f"must be an integer from {low} to {high}"
        return None
    return check


def _number_in(low: float, high: float, unit: str) -> Callable[[Any], str | None]:
    def check(value: Any) -> str | None:
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(value) or not low <= value <= high:
            return f"must be a number from {low:g} to {high:g} {unit}"
        return None
    return check


def _one_of(options: tuple[str, ...]) -> Callable[[Any], str | None]:
    def check(value: Any) -> str | None:
        if value not in options:
            return f"must be one of: {', '.join(options)}"
        return None
    return check


def _text(limit: int) -> Callable[[Any], str | None]:
    def check(value: Any) -> str | None:
        return "must be a string" if not isinstance(value, str) else text_problem(value, limit)
    return check


def _bool(value: Any) -> str | None:
    return None if isinstance(value, bool) else "must be true or false"


def _json_strings(value: Any) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for k, v in value.items() for s in (k, *_json_strings(v))]
    if isinstance(value, list):
        return [s for v in value for s in _json_strings(v)]
    return []


def _json_depth(value: Any) -> int:
    """How many objects and arrays deep ``value`` nests, counted without recursion (so a
    hostile value cannot exhaust the stack while it is being measured)."""
    deepest, level = 0, [(value, 1)]
    while level:
        item, depth = level.pop()
        if isinstance(item, dict | list):
            deepest = max(deepest, depth)
            level.extend((v, depth + 1) for v in (item.values() if isinstance(item, dict)
                                                  else item))
    return deepest


def _attrs(value: Any) -> str | None:
    if not isinstance(value, dict):
        return "must be a JSON object"
    if _json_depth(value) > MAX_ATTRS_DEPTH:
        return DEPTH_PROBLEM
    try:
        size = len(json.dumps(value, allow_nan=False).encode("utf-8"))
    except (ValueError, UnicodeEncodeError):
        return "must be plain JSON (finite numbers, valid Unicode)"
    if size > MAX_ATTRS_BYTES:
        return f"must be at most {MAX_ATTRS_BYTES} bytes of JSON"
    for s in _json_strings(value):
        problem = text_problem(s, MAX_ATTRS_BYTES)
        if problem:
            return f"strings {problem}"
    return None


RULES: dict[str, Callable[[Any], str | None]] = {
    "lanes_forward": _int_in(0, MAX_LANES),
    "lanes_backward": _int_in(0, MAX_LANES),
    "speed_limit_kph": _number_in(*SPEED_RANGE, "km/h"),
    "oneway": _one_of(ONEWAY_VALUES),
    "road_class": _one_of(ROAD_CLASSES),
    "is_junction": _bool,
    "name": _text(MAX_NAME),
    "surface": _text(MAX_SHORT_TEXT),
    "width_m": _number_in(*WIDTH_RANGE, "m"),
    "external_id": _text(MAX_NAME),
    "attrs": _attrs,
}
NODE_RULES: dict[str, Callable[[Any], str | None]] = {
    "traffic_light": _bool,
    "external_id": _text(MAX_NAME),
}
LANE_LINE_WIDTH_RANGE = (0.01, 2.0)  # a painted line, metres
MAX_LANE_POSITION = 32  # as migration 0014's check
LANE_RULES: dict[str, Callable[[Any], str | None]] = {
    "kind": _one_of(LANE_KINDS),
    "colour": _one_of(LANE_COLOURS),
    "width_m": _number_in(*LANE_LINE_WIDTH_RANGE, "m"),
    "position": _int_in(0, MAX_LANE_POSITION),
    "source": _one_of(LANE_SOURCES),
}
KIND_RULES: dict[Kind, dict[str, Callable[[Any], str | None]]] = {
    "segments": RULES, "nodes": NODE_RULES, "lanes": LANE_RULES}
assert set(RULES) == set(SEGMENT_ATTRIBUTES) == set(DEFAULTS["segments"])
assert set(LANE_RULES) == set(LANE_ATTRIBUTES) == set(DEFAULTS["lanes"])
assert set(NODE_RULES) == set(NODE_ATTRIBUTES) == set(DEFAULTS["nodes"])


# Numbers QGIS may send as text: a field typed String by OGR (its first page of items had
# only nulls there) is sent back as "3.5". A plain decimal in JSON's own number syntax means
# one number and nothing else; "3,5", " 3.5", "0x10" or "1e400" stay refused.
INTEGER_TEXT = re.compile(r"-?(0|[1-9][0-9]{0,8})")
NUMBER_TEXT = re.compile(r"-?(0|[1-9][0-9]*)(\.[0-9]+)?([eE][-+]?[0-9]+)?")
NUMERIC_TEXT = {"lanes_forward": INTEGER_TEXT, "lanes_backward": INTEGER_TEXT,
                "speed_limit_kph": NUMBER_TEXT, "width_m": NUMBER_TEXT}


def numbers_from_text(properties: dict[str, Any]) -> dict[str, Any]:
    """``properties`` with the numeric properties given as JSON number text read as numbers
    (``"3.5"`` -> 3.5, ``"2"`` -> 2); any other text is left for the rules to refuse."""
    read = {}
    for key, pattern in NUMERIC_TEXT.items():
        value = properties.get(key)
        if isinstance(value, str) and len(value) <= 32 and pattern.fullmatch(value):
            number = int(value) if pattern is INTEGER_TEXT else float(value)
            if not isinstance(number, float) or math.isfinite(number):
                read[key] = number
    return {**properties, **read}


def field_errors(properties: dict[str, Any], kind: Kind = "segments",
                 read_only: frozenset[str] = frozenset()) -> dict[str, str]:
    """One message per offending field of a merge patch of a feature's properties
    (``read_only``: the kind's properties the server maintains)."""
    rules = KIND_RULES[kind]
    errors: dict[str, str] = {}
    for key, value in properties.items():
        label = key[:100]
        if key in read_only:
            errors[label] = "is read-only"
        elif key not in rules:
            errors[label] = f"is not a {kind[:-1]} attribute"
        elif value is None:
            if key not in NULLABLE:
                errors[label] = "cannot be removed (null)"
        else:
            problem = rules[key](value)
            if problem:
                errors[label] = problem
    return errors


def lanes_consistent(values: dict[str, Any]) -> dict[str, str]:
    """Cross-field rule on the final state: a one-way road has lanes only in its direction."""
    if values["oneway"] == "forward" and values["lanes_forward"] == 0:
        return {"lanes_forward": "a forward one-way road needs at least one forward lane"}
    if values["oneway"] == "backward" and values["lanes_backward"] == 0:
        return {"lanes_backward": "a backward one-way road needs at least one backward lane"}
    if values["lanes_forward"] + values["lanes_backward"] == 0:
        return {"lanes_forward": "a road needs at least one lane"}
    return {}


def merge_patch(target: Any, patch: Any) -> Any:
    """RFC 7396 JSON merge patch."""
    if not isinstance(patch, dict):
        return patch
    result = dict(target) if isinstance(target, dict) else {}
    for key, value in patch.items():
        if value is None:
            result.pop(key, None)
        else:
            result[key] = merge_patch(result.get(key), value)
    return result
