"""Delete a whole road network, and tell every worker's caches at once.

Deleting the ``networks`` row cascades to its nodes, segments and edit history. The change
trigger of migration 0002 cannot announce it (it bumps the network's version, and the row is
gone), so the deletion sends its own ``network_changed`` note, flagged ``"deleted": true``,
with no bounding box: the MVT cache drops every tile of the network and the routing
registries drop its graph. NOTIFY is delivered on commit, so no worker forgets a network that
still exists.
"""

from __future__ import annotations

from dataclasses import dataclass

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.db.notify import CHANNEL
from app.errors import InvalidParameterValueError, UserError
from app.params import parse_slug


@dataclass(frozen=True)
class DeletedNetwork:
    """What went with the network: shown by ``ugvmap network delete``."""

    name: str
    segments: int
    nodes: int
    edits: int


def delete_network(session: Session, name: str) -> DeletedNetwork:
    """Delete network ``name`` with everything in it, in the caller's transaction."""
    try:
        parse_slug(name, "network name")
    except InvalidParameterValueError as exc:
        raise UserError(exc.message) from None
    row = session.execute(text("SELECT id, version FROM networks WHERE name = :n FOR UPDATE"),
                          {"n": name}).first()
    if row is None:
        raise UserError(f"network {name!r} does not exist")
    counts = session.execute(text(
        "SELECT (SELECT count(*) FROM road_segments WHERE network_id = :id), "
        "(SELECT count(*) FROM road_nodes WHERE network_id = :id), "
        "(SELECT count(*) FROM segment_edits WHERE network_id = :id)"), {"id": row.id}).one()
    session.execute(text(
        "SELECT pg_notify(:channel, json_build_object('network_id', CAST(:id AS integer), "
        "'version', CAST(:version AS bigint) + 1, 'bbox', NULL, 'deleted', true)::text)"),
        {"channel": CHANNEL, "id": row.id, "version": row.version})
    session.execute(text("DELETE FROM networks WHERE id = :id"), {"id": row.id})
    return DeletedNetwork(name, counts[0], counts[1], counts[2])
