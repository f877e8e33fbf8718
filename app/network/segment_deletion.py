"""Delete one road segment (``DELETE`` on an OGC API item, as Part 4 spells it) and keep the
topology valid: the nodes it leaves without segments go with it, the others take the kind
their new degree gives them, so ``ugvmap network validate`` stays clean.

Why role editor (not admin, as split and merge): deleting the roads extraction found where
there are none is the core of reviewing an extracted network, which is the map team's
(editors') job. It is as safe as an attribute edit: ``If-Match`` names the version the editor
saw (412 if someone changed the segment since), and the history row keeps the whole segment
(attributes, geometry, end nodes) with who deleted it.

Routing and the tile caches hear of it as of any edit: the change triggers of migration 0002
bump the network's version and NOTIFY the deleted geometry's box when the transaction commits.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.network import collections as colls
from app.network.editing import lock_feature, log_edit
from app.network.tokens import Principal


def delete_segment(session: Session, c: colls.Collection, fid: int, expected: int | None,
                   principal: Principal, *, action: str = "delete",
                   note: dict[str, Any] | None = None) -> None:
    """Delete segment ``fid`` if it is at version ``expected`` (404 / 412 otherwise; None:
    whatever version is current), drop the end nodes it orphans and re-kind the others, and
    log it as ``action`` (with ``note`` as the row's ``new``: why, e.g. the accepted
    preview that replaced it), all in the caller's transaction."""
    feature = lock_feature(session, c, fid, expected)
    props = feature["properties"]
    ends = {"ids": sorted({props["source_node"], props["target_node"]})}
    # Lock the end nodes before counting their segments: two deletions of the two segments
    # at a node must not each see the other still there and leave the node orphaned. (The
    # network's edit lock, taken by lock_feature, serialises them as well; the row locks
    # keep this correct on their own.)
    session.execute(text("SELECT id FROM road_nodes WHERE id = ANY(:ids) ORDER BY id "
                         "FOR UPDATE"), ends)
    session.execute(text("DELETE FROM road_segments WHERE id = :id"), {"id": fid})
    colls.settle_nodes(session, ends["ids"])
    log_edit(session, c, fid, action, props["version"], None, principal,
             {**props, "geometry": feature["geometry"]}, note,
             conditional=expected is not None)
