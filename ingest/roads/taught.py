"""What the map team has taught the extraction of a layer: the labels stored with the layer
(:mod:`app.labels.store`, drawn in the web map or added with ``ugvmap layers labels``) and
the review of the networks extracted from it (:mod:`ingest.roads.review`).

Every extraction of the layer (``ugvmap ingest roads --layer``, the ``ingest-roads`` job)
adds them to whatever sample it was given, without being asked, so a team's corrections are
not lost on the next survey of the same area or the next tile of the same mosaic; the job's
report says how many of each it used (``--no-labels`` / ``--no-review-labels`` leave them
out).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from shapely.geometry import shape
from sqlalchemy.orm import Session

from app.labels.store import list_labels
from ingest.roads.review import ReviewLabels, counted, review_labels
from ingest.roads.sample import GeoSample


@dataclass(frozen=True)
class LayerLabels:
    """A layer's stored labels as a sample (partial lines), and how many of each kind."""

    layer: str
    sample: GeoSample
    road_lines: int = 0
    not_road_lines: int = 0
    not_road_areas: int = 0

    @property
    def count(self) -> int:
        """How many labels the layer holds."""
        return self.road_lines + self.not_road_lines + self.not_road_areas

    def describe(self) -> str:
        """E.g. ``12 labels of layer vegas (7 road lines, 5 not-road areas)``."""
        parts = [counted(n, what) for n, what in ((self.road_lines, "road line"),
                                                  (self.not_road_lines, "not-road line"),
                                                  (self.not_road_areas, "not-road area"))
                 if n]
        return f"{counted(self.count, 'label')} of layer {self.layer}" + (
            f" ({', '.join(parts)})" if parts else "")


def layer_labels(session: Session, slug: str) -> LayerLabels:
    """The labels stored with layer ``slug``: road lines, not-road lines and areas."""
    road, not_road, areas = [], [], []
    for feature in list_labels(session.connection(), slug):
        geometry = shape(feature["geometry"])
        if feature["properties"]["label"] == "road":
            road.append(geometry)
        elif geometry.geom_type == "Polygon":
            areas.append(geometry)
        else:
            not_road.append(geometry)
    return LayerLabels(slug, GeoSample(road_lines=road, not_road_lines=not_road,
                                       not_road_areas=areas),
                       len(road), len(not_road), len(areas))


@dataclass(frozen=True)
class Taught:
    """The layer's labels and review labels an extraction uses (None: left out)."""

    labels: LayerLabels | None
    review: ReviewLabels | None

    @property
    def sample(self) -> GeoSample:
        """Both as one sample (partial lines)."""
        return merged(*(t.sample for t in (self.labels, self.review) if t is not None)) \
            or GeoSample()

    def describe(self) -> str | None:
        """The report's line, e.g. ``sample: 12 labels of layer vegas (...); 31 review labels
        from network vegas-roads (30 deleted, 1 drawn)``; None when neither gave a label."""
        used = [t.describe() for t in (self.labels, self.review) if t is not None and t.count]
        return "sample: " + "; ".join(used) if used else None


def taught(session: Session, slug: str, *, labels: bool = True, review: bool = True) -> Taught:
    """What the map team taught about layer ``slug`` (either part left out when False)."""
    return Taught(layer_labels(session, slug) if labels else None,
                  review_labels(session, slug) if review else None)


def merged(*samples: GeoSample | None) -> GeoSample | None:
    """One sample holding every label of ``samples`` (None: none had any). The first one
    given sets how lines are read (their width; complete or partial; open ends): a complete
    sample (a drive, every known road) stays complete, and extra road lines only narrow
    what it calls "not road"."""
    given = [s for s in samples if s is not None and not s.empty]
    if len(given) < 2:
        return given[0] if given else None
    return replace(given[0], road_boxes=[b for s in given for b in s.road_boxes],
                   not_road_boxes=[b for s in given for b in s.not_road_boxes],
                   road_lines=[g for s in given for g in s.road_lines],
                   not_road_lines=[g for s in given for g in s.not_road_lines],
                   not_road_areas=[g for s in given for g in s.not_road_areas])
