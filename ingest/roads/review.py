"""Review edits are labels: what a map team did to the networks extracted from a layer, read
back as a training sample for the layer's next extraction.

A reviewer who deletes a false road (a parking aisle, a field edge, a canal) has said "this
is not a road"; one who draws a missing road, moves a segment onto the road or edits a
segment and keeps it has said "this is a road". The edit history (``segment_edits``) keeps
both, so the next extraction of the layer (the same area again, or a new tile of the same
mosaic) learns from them without anyone labelling twice:

- a **deleted** segment that the extraction had drawn (``attrs.extracted_from`` is the
  layer) is a not-road line along the geometry it had when deleted; a segment a person
  drew and deleted again says nothing;
- a segment still in the network that a person **drew** (created), **moved** (an edit of its
  geometry: a PATCH/PUT of it, a split, a merge, a node moved under it) or **confirmed**
  (an edit of its attributes only: they looked at it and kept it) is a road line along its
  current geometry.

An accepted road preview (history action ``accept``, :mod:`app.previews.accept`) or an
accepted re-survey (``resurvey``, ``resurvey-revert``) is the model's or another survey's
work put in by a person's one click, not a review of each road: neither the roads it added
nor those it moved or replaced are labels.

The lines are partial (``not_road_beyond_m`` None): a reviewer fixes some roads and says
nothing about the rest of the image.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

from shapely.geometry import shape
from shapely.geometry.base import BaseGeometry
from sqlalchemy import text
from sqlalchemy.orm import Session

from app.network.resurvey.changes import MACHINE_ACTIONS
from ingest.roads.sample import GeoSample

# Edits that change a kept segment's line (besides a PATCH/PUT whose new values hold it).
GEOMETRY_ACTIONS = ("split", "merge", "move-node")
NETWORKS = (
    "SELECT n.id, n.name FROM networks n WHERE EXISTS (SELECT 1 FROM road_segments s "
    "  WHERE s.network_id = n.id AND s.attrs->>'extracted_from' = :slug) "
    "OR EXISTS (SELECT 1 FROM segment_edits e WHERE e.network_id = n.id "
    "  AND e.action = 'delete' AND e.old->'attrs'->>'extracted_from' = :slug) ORDER BY n.name")
DELETED = (
    "SELECT (e.old->'geometry')::text FROM segment_edits e WHERE e.network_id = ANY(:nets) "
    "AND e.action = 'delete' AND e.old->'attrs'->>'extracted_from' = :slug ORDER BY e.id")
# Each kept segment once: how it came to be reviewed, and its line as it is now.
KEPT = (
    "SELECT ST_AsGeoJSON(s.geom, 9) AS geometry, "
    "  bool_or(e.action = 'create') AS drawn, "
    "  bool_or(e.new ? 'geometry' OR e.action = ANY(:geometry_actions)) AS moved "
    "FROM road_segments s JOIN segment_edits e "
    "  ON e.network_id = s.network_id AND e.segment_id = s.id "
    "WHERE s.network_id = ANY(:nets) AND e.action <> 'delete' "
    "  AND e.action <> ALL(:machine) "
    "GROUP BY s.id ORDER BY s.id")


@dataclass(frozen=True)
class ReviewLabels:
    """The review of a layer's extracted networks as a sample, and what it was made of."""

    sample: GeoSample
    networks: tuple[str, ...] = ()
    deleted: int = 0
    """Extracted segments a person deleted: not-road lines."""
    drawn: int = 0
    """Segments a person created: road lines."""
    moved: int = 0
    """Segments whose line a person changed: road lines."""
    confirmed: int = 0
    """Segments a person edited and kept as they were drawn: road lines."""

    @property
    def count(self) -> int:
        """How many labels the review gives."""
        return self.deleted + self.drawn + self.moved + self.confirmed

    def describe(self) -> str:
        """E.g. ``31 review labels from network vegas-roads (30 deleted, 1 drawn)``."""
        parts = [f"{n} {what}" for n, what in ((self.deleted, "deleted"), (self.drawn, "drawn"),
                                               (self.moved, "moved"),
                                               (self.confirmed, "confirmed")) if n]
        source = (f"network{'s' if len(self.networks) > 1 else ''} {', '.join(self.networks)}"
                  if self.networks else "no network extracted from the layer")
        return (f"{counted(self.count, 'review label')} from {source}"
                + (f" ({', '.join(parts)})" if parts else ""))


def counted(n: int, noun: str) -> str:
    """``1 road line``, ``2 road lines``: a count in a report."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def _geometry(geojson: str) -> BaseGeometry:
    return shape(json.loads(geojson))


def review_labels(session: Session, slug: str) -> ReviewLabels:
    """The labels the review of the networks extracted from layer ``slug`` gives (module
    docstring); an empty sample when none was extracted or nobody edited them."""
    found = session.execute(text(NETWORKS), {"slug": slug}).all()
    nets = [row.id for row in found]
    if not nets:
        return ReviewLabels(GeoSample())
    geometries: list[str] = list(session.execute(
        text(DELETED), {"nets": nets, "slug": slug}).scalars())
    deleted = [_geometry(g) for g in geometries]
    kept = session.execute(text(KEPT), {"nets": nets, "machine": list(MACHINE_ACTIONS),
                                        "geometry_actions": list(GEOMETRY_ACTIONS)}).all()
    drawn = sum(1 for row in kept if row.drawn)
    moved = sum(1 for row in kept if row.moved and not row.drawn)
    return ReviewLabels(
        GeoSample(road_lines=[_geometry(row.geometry) for row in kept],
                  not_road_lines=deleted),
        tuple(row.name for row in found), deleted=len(deleted), drawn=drawn, moved=moved,
        confirmed=len(kept) - drawn - moved)
