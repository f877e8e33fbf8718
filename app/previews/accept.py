"""Accept a road preview into a network: the preview's roads are matched against the network's
roads of its view, as a re-survey is (:mod:`app.network.resurvey`), and what they change is
applied where nobody reviewed it; nothing a person did is undone.

Why matching and not "delete the view's extracted roads, add the preview's": a preview that
finds a road the network already has would replace it by a new segment of a new id, so every
accept churned ids and histories (a vehicle's mission referring to a segment lost it) and a
second accept of the same view replaced every road again. Matched, such a road is *unchanged*
and kept as it is.

In one transaction, under the network's edit lock and its re-survey lock (one update at a
time), and with the layer row share-locked (no re-ingest commits meanwhile):

1. the preview must still be of the layer's current version (else 409: the imagery changed);
2. its roads are matched against the network inside the preview's box, and the result is a
   change set (source ``preview N of layer L``), listed with the network's re-surveys;
3. accepted at once: every *new* road, and each *moved* or *missing* segment that was
   extracted from this layer (``attrs.extracted_from``) and that no person edited. Proposals
   on a person's segments and on roads of other sources (an OSM import) stay proposed, for
   the review tool, one by one.

Every change is a history row with action ``accept`` naming the preview, the change set and
the change, so review edits read as labels (a person's) stay apart from accepted extraction
(the model's), and the whole accept is reverted in one step as its change set.
"""

from __future__ import annotations

from typing import Any

import shapely
from sqlalchemy import text
from sqlalchemy.orm import Session

from app.errors import InvalidValueError, StalePreviewError
from app.network import collections as colls
from app.network.editing import lock_topology
from app.network.resurvey import changes
from app.network.tokens import Principal
from app.previews.store import stored_preview

# Applied at once: new roads, and moves and deletions of unreviewed roads of this layer.
APPLICABLE = (
    "SELECT p.id FROM proposed_changes p LEFT JOIN road_segments s ON s.id = p.segment_id "
    "WHERE p.change_set_id = :set AND NOT p.edited "
    "AND (p.kind = 'new' OR s.attrs->>'extracted_from' = :slug) ORDER BY p.id")
DECIDED = ("SELECT kind, status, count(*) AS n FROM proposed_changes "
           "WHERE change_set_id = :set GROUP BY kind, status")


def _network(session: Session, name: Any) -> colls.Collection:
    row = colls.network_row(session, name) if isinstance(name, str) else None
    if row is None:
        raise InvalidValueError(f"no network {str(name)[:100]!r} to accept the preview into "
                                "(see GET /networks)", errors={"network": "is not a network"})
    return colls.Collection(name, row.id, "segments", row.title)


def accept_preview(session: Session, slug: str, preview_id: int, network: Any,
                   principal: Principal) -> dict[str, Any]:
    """Put preview ``preview_id`` of layer ``slug`` into ``network`` (in the caller's
    transaction). Answers the change set's id and counts: roads ``added``, ``moved`` and
    ``removed``; ``kept`` (the preview saw them where they are); ``left`` (proposals on a
    person's roads or another source's, for review)."""
    c = _network(session, network)
    lock_topology(session, c)
    preview = stored_preview(session, slug, preview_id)
    if preview.layer_version != preview.current:
        raise StalePreviewError(
            f"the layer changed since this preview (it was made from version "
            f"{preview.layer_version}, the layer is at version {preview.current}); preview "
            "again")
    features = preview.result["features"]
    if not features:
        raise InvalidValueError(
            f"preview {preview_id} found no roads in its view: nothing to accept (a road "
            "the network has there and should not is deleted in the editor, and the "
            "deletion teaches the next extraction)", errors={"preview": "has no roads"})
    lines = [changes.SurveyLine([tuple(p[:2]) for p in f["geometry"]["coordinates"]],
                                dict(f["properties"])) for f in features]
    proposed = changes.propose(session, c.network, lines,
                               source=f"preview {preview_id} of layer {slug}",
                               coverage=shapely.from_wkt(preview.bbox), principal=principal,
                               layer=(preview.layer_id, preview.layer_version),
                               elsewhere=True)
    set_id = proposed["id"]
    ids: tuple[int, ...] = tuple(session.execute(
        text(APPLICABLE), {"set": set_id, "slug": slug}).scalars())
    if ids:
        changes.accept(session, c.network, set_id, changes.Selection(ids=ids), principal,
                       action=changes.PREVIEW_ACCEPTED,
                       note={"preview": preview_id, "layer": slug})
    done = {(r.kind, r.status): r.n for r in session.execute(text(DECIDED), {"set": set_id})}
    return {"change_set": set_id,
            "added": done.get(("new", "accepted"), 0),
            "moved": done.get(("moved", "accepted"), 0),
            "removed": done.get(("missing", "accepted"), 0),
            "kept": proposed["counts"].get("unchanged", 0),
            "left": sum(n for (_, status), n in done.items() if status == "proposed")}
