"""SpaceNet 3 road labels (``road_type``, ``lane_number``, ``one_way_ty``, ``speed_mph``...)
to segment attributes.

SpaceNet is the public benchmark for road extraction from imagery, so ground-truth files in
its schema are what a team compares an extracted network with; mapping the codes to our
columns makes such a file routable with real lanes and speeds instead of defaults. Codes per
the SpaceNet 3 schema: road_type 1 motorway .. 7 cart track; one_way_ty 1 = one-way
(along the geometry), 2 = two-way; paved 1 = paved, 2 = unpaved; lane_number counts all lanes.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ingest.network.model import RoadAttributes

SPACENET_KEYS = frozenset({"road_type", "lane_number", "one_way_ty"})
ROAD_TYPES = {"1": "motorway", "2": "primary", "3": "secondary", "4": "tertiary",
              "5": "residential", "6": "unclassified", "7": "track"}
MAPPED = frozenset({"road_type", "road_id", "lane_number", "one_way_ty", "paved", "speed_mph",
                    "speed_m/s"})
MPH_TO_KPH = 1.609344
MAX_LANES = 8


def is_spacenet(props: Mapping[str, Any]) -> bool:
    """Whether a feature carries SpaceNet's road-label attributes (then they are mapped, not kept
    raw)."""
    return props.keys() >= SPACENET_KEYS


def _code(value: Any) -> str:
    return str(value).strip().split(".")[0] if value is not None else ""


def attributes_from_spacenet(props: Mapping[str, Any]) -> RoadAttributes:
    """Lanes of a two-way road are split over both directions (at least one each way)."""
    lanes = min(MAX_LANES, max(1, int(float(props.get("lane_number") or 1))))
    oneway = _code(props.get("one_way_ty")) == "1"
    speed = props.get("speed_mph")
    speed_kph = round(float(speed) * MPH_TO_KPH, 1) if speed is not None and speed != "" else None
    if speed_kph is not None and not 5 <= speed_kph <= 150:
        speed_kph = None
    surface = {"1": "paved", "2": "unpaved"}.get(_code(props.get("paved")))
    return RoadAttributes(
        lanes_forward=lanes if oneway else max(1, (lanes + 1) // 2),
        lanes_backward=0 if oneway else max(1, lanes // 2),
        speed_limit_kph=speed_kph,
        oneway="forward" if oneway else "none",
        road_class=ROAD_TYPES.get(_code(props.get("road_type")), "unclassified"),
        surface=surface,
        external_id=_code(props.get("road_id")) or None,
        attrs={k: v for k, v in props.items() if k not in MAPPED and v is not None},
    )
