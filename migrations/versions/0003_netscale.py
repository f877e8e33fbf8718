"""Country-size networks: quiet bulk loads, and an index for per-zoom class filtering.

- ``ugvmap_network_changed()`` (the trigger function of ``0002_network_change_notify``)
  returns at once while the transaction's setting ``ugvmap.bulk_load`` is ``on``. A streamed
  import sets it, writes a million rows in a few statements, and bumps the network version once
  with no bounding box (``ugvmap_network_bump(id, NULL)``: "reload the whole network"), so
  listeners reload once instead of computing and applying the extent of every bulk statement.
  Any other session (PATCH, psql) never sets it and notifies exactly as before.
- ``(network_id, road_class)`` lets low-zoom vector tiles, which show only a few road classes,
  read just those rows instead of every segment under the tile.

Revision ID: 0003_netscale
Revises: 0002_network_change_notify
Create Date: 2026-11-23
"""

import importlib

from alembic import op

revision = "0003_netscale"
down_revision = "0002_network_change_notify"
branch_labels = None
depends_on = None

_0002 = importlib.import_module("migrations.versions.0002_network_change_notify")
GUARD = """    IF current_setting('ugvmap.bulk_load', true) = 'on' THEN
        RETURN NULL;  -- a bulk load announces itself once, when it is done
    END IF;
"""


def _changed(guarded: bool) -> str:
    sql = _0002.CHANGED.replace("CREATE FUNCTION", "CREATE OR REPLACE FUNCTION", 1)
    return sql.replace("BEGIN\n", "BEGIN\n" + GUARD, 1) if guarded else sql


def upgrade() -> None:
    op.execute(_changed(guarded=True))
    op.create_index("ix_road_segments_network_class", "road_segments",
                    ["network_id", "road_class"])


def downgrade() -> None:
    op.drop_index("ix_road_segments_network_class", "road_segments")
    op.execute(_changed(guarded=False))
