"""OpenStreetMap tags to segment attributes, and back (for the OSM export).

Rules follow the OSM wiki: ``maxspeed`` may be km/h, ``mph``, ``knots``, ``walk`` or ``none``
(or a country code like ``DE:urban``, which we cannot resolve without a table and leave empty);
``lanes`` is split evenly over the directions unless ``lanes:forward``/``lanes:backward`` say
otherwise; ``oneway=yes|true|1`` is forward, ``-1|reverse`` is backward, ``reversible`` and
``alternating`` are kept as two-way (the direction changes with time); ``junction=roundabout``
and ``circular`` imply one-way unless ``oneway=no`` says otherwise.
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from ingest.network.model import RoadAttributes

# Tags consumed into columns; every other tag is kept verbatim in ``attrs``.
EXTERNAL_ID_TAG = "ugvmap:external_id"
CONFIDENCE_TAG = "ugvmap:confidence"
BOTH_WAYS_TAG = "lanes:both_ways"
"""OSM's centre lane shared by both directions (e.g. a turn lane), counted in ``lanes``."""

# ``junction`` stays in attrs too (unless it is a bare "yes"): its value (roundabout,
# circular...) is more than the ``is_junction`` flag.
MAPPED_TAGS = frozenset({"highway", "maxspeed", "lanes", "lanes:forward", "lanes:backward",
                         "oneway", "name", "surface", "width", EXTERNAL_ID_TAG,
                         CONFIDENCE_TAG})

# highway=* values that are not drivable or walkable lines (plans, areas, points).
NOT_ROADS = frozenset({"proposed", "construction", "abandoned", "disused", "razed", "platform",
                       "rest_area", "services", "bus_stop", "elevator", "emergency_bay"})

SPEED_WALK_KPH = 5.0
SPEED_NONE_KPH = 150.0  # "no limit": capped at the highest speed we store as valid
MAX_LANES = 8

_NUMBER = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(mph|knots|km/h|kmh|kph)?\s*$", re.IGNORECASE)
_WIDTH = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(m)?\s*$", re.IGNORECASE)
_UNIT_FACTOR = {"mph": 1.609344, "knots": 1.852}


def is_road(tags: Mapping[str, str]) -> bool:
    """A way we import: any linear ``highway=*`` that is not a plan, an area or a point."""
    highway = tags.get("highway")
    return bool(highway) and highway not in NOT_ROADS and tags.get("area") != "yes"


def parse_maxspeed(value: str | None) -> float | None:
    """``"50"``, ``"30 mph"``, ``"walk"``, ``"none"`` -> km/h; ``None`` when unparseable."""
    if not value:
        return None
    text = value.split(";")[0].strip().lower()
    if text == "walk":
        return SPEED_WALK_KPH
    if text == "none":
        return SPEED_NONE_KPH
    match = _NUMBER.match(text)
    if not match:
        return None
    kph = float(match.group(1)) * _UNIT_FACTOR.get((match.group(2) or "").lower(), 1.0)
    return round(kph, 3) if 1 <= kph <= 200 else None


def parse_confidence(value: str | None) -> float | None:
    """``ugvmap:confidence`` (our exports) as 0..1; None when absent or not a share."""
    try:
        share = float(value) if value else None
    except ValueError:
        return None
    return share if share is not None and 0.0 <= share <= 1.0 else None


def _parse_count(value: str | None) -> int | None:
    if not value:
        return None
    try:
        count = int(float(value.split(";")[0]))
    except ValueError:
        return None
    return count if 0 <= count <= MAX_LANES * 2 else None


def parse_oneway(tags: Mapping[str, str]) -> str:
    """OSM ``oneway`` as ``forward``/``backward``/``none`` (reversible roads count as two-way for a
    planner)."""
    value = (tags.get("oneway") or "").strip().lower()
    if value in ("yes", "true", "1"):
        return "forward"
    if value in ("-1", "reverse"):
        return "backward"
    if value in ("no", "false", "0", "reversible", "alternating"):
        return "none"
    if tags.get("junction") in ("roundabout", "circular"):
        return "forward"
    return "none"


def _lanes(tags: Mapping[str, str], oneway: str) -> tuple[int, int]:
    forward = _parse_count(tags.get("lanes:forward"))
    backward = _parse_count(tags.get("lanes:backward"))
    total = _parse_count(tags.get("lanes"))
    if oneway == "forward":
        return min(forward or total or 1, MAX_LANES), 0
    if oneway == "backward":
        return 0, min(backward or total or 1, MAX_LANES)
    if forward is None and backward is None:
        if total is None:
            return 1, 1
        forward = max(total - total // 2, 1) if total else 0
        backward = total // 2 if total > 1 else forward
    elif forward is None and backward is not None:
        forward = max((total or 0) - backward, 1)
    elif backward is None and forward is not None:
        backward = max((total or 0) - forward, 1)
    assert forward is not None and backward is not None  # each branch above sets both
    return min(forward, MAX_LANES), min(backward, MAX_LANES)


def _parse_width(value: str | None) -> float | None:
    match = _WIDTH.match(value or "")
    width = float(match.group(1)) if match else None
    return width if width and width > 0 else None


def osm_external_id(kind: str, osm_id: int) -> str | None:
    """``w123`` / ``n45`` for an object of OSM; None for an id <= 0, which is a placeholder
    for an object not (yet) in OSM (JOSM's convention, and our export's)."""
    return f"{kind}{osm_id}" if osm_id > 0 else None


def attributes_from_tags(tags: Mapping[str, str], external_id: str | None = None
                         ) -> RoadAttributes:
    """Map one OSM way's tags to segment attributes; unmapped tags go to ``attrs``."""
    oneway = parse_oneway(tags)
    forward, backward = _lanes(tags, oneway)
    return RoadAttributes(
        lanes_forward=forward,
        lanes_backward=backward,
        speed_limit_kph=parse_maxspeed(tags.get("maxspeed")),
        oneway=oneway,
        road_class=tags.get("highway") or "unclassified",
        is_junction=bool(tags.get("junction")) and tags.get("junction") != "no",
        name=tags.get("name"),
        surface=tags.get("surface"),
        width_m=_parse_width(tags.get("width")),
        # Our export writes the tag even when empty: "no external id", not "use the way id".
        external_id=(tags[EXTERNAL_ID_TAG] or None) if EXTERNAL_ID_TAG in tags else external_id,
        attrs={k: v for k, v in tags.items()
               if k not in MAPPED_TAGS and not (k == "junction" and v == "yes")},
        confidence=parse_confidence(tags.get(CONFIDENCE_TAG)),
    )


def tags_from_attributes(a: RoadAttributes) -> dict[str, str]:
    """The inverse of :func:`attributes_from_tags`, explicit enough to round-trip exactly."""
    tags = {str(k): str(v) for k, v in a.attrs.items()}
    tags["highway"] = a.road_class
    tags["oneway"] = {"forward": "yes", "backward": "-1"}.get(a.oneway, "no")
    tags["lanes:forward"] = str(a.lanes_forward)
    tags["lanes:backward"] = str(a.lanes_backward)
    both_ways = _parse_count(tags.get(BOTH_WAYS_TAG)) or 0
    tags["lanes"] = str(a.lanes_forward + a.lanes_backward + both_ways)
    if a.speed_limit_kph is not None:
        tags["maxspeed"] = repr(float(a.speed_limit_kph)).removesuffix(".0")
    if a.is_junction:
        tags.setdefault("junction", "yes")
    else:
        tags.pop("junction", None)
    for key, value in (("name", a.name), ("surface", a.surface)):
        if value is not None:
            tags[key] = value
    tags[EXTERNAL_ID_TAG] = a.external_id or ""
    if a.width_m is not None:
        tags["width"] = repr(float(a.width_m))
    if a.confidence is not None:
        tags[CONFIDENCE_TAG] = repr(float(a.confidence))
    return tags
