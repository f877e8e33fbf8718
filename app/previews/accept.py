"""Accept a road preview into a network: the preview's roads replace the network's roads of
the same window that nobody has reviewed, and nothing a person did is undone.

In one transaction, under the network's edit lock (as every edit of it,
:func:`app.network.editing.lock_topology`), and with the layer row share-locked (no re-ingest
commits meanwhile):

1. the preview must still be of the layer's current version (else 409: the imagery changed);
2. the network's *unreviewed extracted* segments lying in the preview's window are deleted:
   extracted from this layer (``attrs.extracted_from``) and with no edit in their history but
   earlier accepts (an accepted preview is the model's work, not a person's review). Segments
   a person created or edited, and those of other sources, are kept;
3. each preview road is added as the editing API's POST adds one (noded into the network at
   its ends: :func:`~app.network.segment_editing.create_segment`), unless it duplicates a kept
   road: most of it (:data:`DUPLICATE_SHARE`) within :data:`DUPLICATE_M` of one. A road the
   POST would refuse (both ends on one node, an exact duplicate) is left out alone, in its
   own savepoint, so it cannot undo the rest.

Every deletion and creation is a history row with action ``accept`` and the preview's id, so
review edits read as labels (a person's) stay apart from accepted extraction (the model's).
"""

from __future__ import annotations

import json
from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.errors import InvalidValueError, StalePreviewError
from app.network import collections as colls
from app.network import crs as crs_
from app.network.editing import lock_topology
from app.network.segment_deletion import delete_segment
from app.network.segment_editing import create_segment
from app.network.tokens import Principal
from app.previews.store import stored_preview

ACTION = "accept"
DUPLICATE_M = 3.0
"""A preview road this close to a kept road, along most of its length, is that road again."""
DUPLICATE_SHARE = 0.5
DUPLICATE_SAMPLES = 20
"""Points along a preview road at which its distance to the kept roads is measured."""

UNREVIEWED = (
    "SELECT s.id FROM road_segments s WHERE s.network_id = :n "
    "AND s.attrs->>'extracted_from' = :slug AND ST_CoveredBy(s.geom, CAST(:box AS geometry)) "
    "AND NOT EXISTS (SELECT 1 FROM segment_edits e WHERE e.network_id = s.network_id "
    f"  AND e.segment_id = s.id AND e.action <> '{ACTION}') ORDER BY s.id")
IN_BOX = ("SELECT count(*) FROM road_segments s WHERE s.network_id = :n "
          "AND ST_Intersects(s.geom, CAST(:box AS geometry))")
DUPLICATED = (
    "SELECT avg((EXISTS (SELECT 1 FROM road_segments s WHERE s.network_id = :n "
    "  AND ST_DWithin(s.geom::geography, p.geom::geography, :m)))::int) "
    "FROM ST_DumpPoints(ST_LineInterpolatePoints("
    "  ST_SetSRID(ST_GeomFromGeoJSON(:g), 4326), :step)) p")


def _network(session: Session, name: Any) -> colls.Collection:
    row = colls.network_row(session, name) if isinstance(name, str) else None
    if row is None:
        raise InvalidValueError(f"no network {str(name)[:100]!r} to accept the preview into "
                                "(see GET /networks)", errors={"network": "is not a network"})
    return colls.Collection(name, row.id, "segments", row.title)


def accept_preview(session: Session, slug: str, preview_id: int, network: Any,
                   principal: Principal) -> dict[str, int]:
    """Put preview ``preview_id`` of layer ``slug`` into ``network`` (in the caller's
    transaction); the counts of segments removed, added, kept, and preview roads left out
    as duplicates of kept ones."""
    c = _network(session, network)
    lock_topology(session, c)
    preview = stored_preview(session, slug, preview_id)
    if preview.layer_version != preview.current:
        raise StalePreviewError(
            f"the layer changed since this preview (it was made from version "
            f"{preview.layer_version}, the layer is at version {preview.current}); preview "
            "again")
    where = {"n": c.network_id, "slug": slug, "box": preview.bbox}
    note = {"preview": preview_id, "layer": slug}
    removed: list[int] = list(session.execute(text(UNREVIEWED), where).scalars())
    for fid in removed:
        delete_segment(session, c, fid, None, principal, action=ACTION, note=note)
    kept = int(session.execute(text(IN_BOX), where).scalar_one())
    added = duplicates = 0
    for feature in preview.result["features"]:
        geometry = json.dumps(feature["geometry"])
        share: float | None = session.execute(text(DUPLICATED), {
            "n": c.network_id, "m": DUPLICATE_M, "g": geometry,
            "step": 1 / DUPLICATE_SAMPLES}).scalar_one()
        if share is not None and share > DUPLICATE_SHARE:
            duplicates += 1
            continue
        properties = dict(feature["properties"])
        confidence = properties.pop("confidence", None)
        savepoint = session.begin_nested()
        try:
            create_segment(session, c, {**feature, "properties": properties}, crs_.DEFAULT,
                           principal, action=ACTION, note=note, confidence=confidence)
        except InvalidValueError:
            savepoint.rollback()
            duplicates += 1
            continue
        savepoint.commit()
        added += 1
    return {"removed": len(removed), "added": added, "kept": kept,
            "duplicates": duplicates}
