"""The in-memory shapes a network import passes around, independent of any file format.

Readers (OSM, GeoJSON, GeoPackage, road extraction) all produce ``RoadLine`` objects; the
noding step and the database writer only ever see those, so every source goes through the
same topology rules.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any, Protocol, runtime_checkable

Coord = tuple[float, float]

ONEWAY_VALUES = ("none", "forward", "backward")


@dataclass
class RoadAttributes:
    """The planner-facing attributes of a road, one field per ``road_segments`` column."""

    lanes_forward: int = 1
    lanes_backward: int = 1
    speed_limit_kph: float | None = None
    oneway: str = "none"
    road_class: str = "unclassified"
    is_junction: bool = False
    name: str | None = None
    surface: str | None = None
    width_m: float | None = None
    external_id: str | None = None
    attrs: dict[str, Any] = field(default_factory=dict)
    confidence: float | None = None
    """How sure road extraction was of the segment (0..1); None = not extracted from imagery."""


ATTRIBUTE_NAMES = tuple(f.name for f in fields(RoadAttributes))


@dataclass
class RoadLine:
    """One attributed polyline in lon/lat (EPSG:4326), before noding."""

    coords: list[Coord]
    attributes: RoadAttributes = field(default_factory=RoadAttributes)


@runtime_checkable
class GeoInterface(Protocol):
    """Anything exposing ``__geo_interface__`` (shapely geometries, geojson features...)."""

    @property
    def __geo_interface__(self) -> Mapping[str, Any]: ...


FeatureLike = RoadLine | Mapping[str, Any] | GeoInterface


@dataclass
class NodePoint:
    """Attributes that belong to a node rather than a segment (e.g. a traffic light)."""

    coord: Coord
    traffic_light: bool = False
    external_id: str | None = None


@dataclass
class ImportSummary:
    """What an import wrote, for the CLI and for tests."""

    network: str
    network_id: int
    segments: int
    nodes: int
    total_length_m: float
    lines_read: int
    duplicates_dropped: int = 0
    crossings_noded: int = 0
