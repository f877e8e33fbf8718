"""The attribute rules road extraction applies, and what a network's ``settings`` may hold.

One pydantic model with the documented defaults, so a rule table is checked the same way
wherever it comes from (``ugvmap ingest roads --speed-table``, a queued job's ``rules``,
``ugvmap network settings``) and bad values are refused before anything is written. A network
stores only what it overrides (``networks.settings["attributes"]``: the fields a user set), so a
default changed here reaches every network that did not override it. The rules themselves
(how width and position become lanes, class and speed) are :mod:`ingest.roads.attributes`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated, Any

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, ValidationError

from app.errors import UserError
from app.network.validation import ROAD_CLASSES, SPEED_RANGE

SETTINGS_KEY = "attributes"
"""Where the attribute rules live in ``networks.settings`` (other features may add keys)."""


def _known_class(name: str) -> str:
    if name not in ROAD_CLASSES:
        raise ValueError(f"{name!r} is not a road class ({', '.join(ROAD_CLASSES)})")
    return name


RoadClass = Annotated[str, AfterValidator(_known_class)]
Speed = Annotated[float, Field(ge=SPEED_RANGE[0], le=SPEED_RANGE[1])]


class ClassRule(BaseModel):
    """A row of the class table: a segment at least this wide and this central gets the class."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    road_class: RoadClass
    min_width_m: float = Field(default=0.0, ge=0, le=100)
    min_through: float = Field(default=0.0, ge=0, le=1)
    """Share of the busiest segment's through traffic (edge betweenness), 0..1."""


DEFAULT_CLASSES = (
    ClassRule(road_class="secondary", min_width_m=10.0, min_through=0.5),
    ClassRule(road_class="tertiary", min_width_m=6.5, min_through=0.2),
    ClassRule(road_class="residential", min_width_m=4.5),
    ClassRule(road_class="service"),
)
DEFAULT_SPEEDS_KPH: dict[str, float] = {
    "motorway": 100.0, "trunk": 80.0, "primary": 60.0, "secondary": 50.0, "tertiary": 40.0,
    "unclassified": 30.0, "residential": 30.0, "living_street": 10.0, "service": 20.0,
    "track": 15.0,
}


class AttributeRules(BaseModel):
    """Every rule's parameters; a field left out keeps the default (or the network's value)."""

    model_config = ConfigDict(extra="forbid")

    lane_width_m: float = Field(default=3.5, ge=1.5, le=10)
    """Width of one lane: lanes = round(width / lane_width)."""
    classes: tuple[ClassRule, ...] = Field(default=DEFAULT_CLASSES, min_length=1, max_length=50)
    """Checked top-down; the first row a segment meets gives its class (none: unclassified)."""
    speed_kph: dict[RoadClass, Speed | None] = Field(default_factory=dict)
    """Speeds per class on top of :data:`DEFAULT_SPEEDS_KPH`; null = no speed limit."""
    junction_length_m: float = Field(default=10.0, ge=0, le=100)
    """A segment between two junction nodes no longer than this lies inside one junction."""

    def speed(self, road_class: str) -> float | None:
        """The default speed of ``road_class``: this table's, else the documented default."""
        if road_class in self.speed_kph:
            return self.speed_kph[road_class]
        return DEFAULT_SPEEDS_KPH.get(road_class)

    def overrides(self) -> dict[str, Any]:
        """What was set explicitly (what a network stores), as JSON."""
        return self.model_dump(mode="json", exclude_unset=True)

    def updated(self, overrides: AttributeRules) -> AttributeRules:
        """These rules with ``overrides``' explicit fields on top; speed tables are merged class
        by class (a table naming one class keeps the others' speeds)."""
        merged = {**self.overrides(), **overrides.overrides()}
        if self.speed_kph or overrides.speed_kph:
            merged["speed_kph"] = {**self.speed_kph, **overrides.speed_kph}
        return AttributeRules.model_validate(merged)


def rules_from(document: Mapping[str, Any], what: str) -> AttributeRules:
    """Rules (or overrides) from JSON; a :class:`UserError` naming each bad field otherwise."""
    try:
        return AttributeRules.model_validate(document)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(str(p) for p in e['loc']) or 'value'}: {e['msg']}"
                             for e in exc.errors())
        raise UserError(f"{what}: {problems}") from None
