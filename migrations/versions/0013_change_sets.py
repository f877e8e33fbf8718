"""Change sets: what a re-survey (``ingest roads|network ... --update``) proposes for a network.

- ``change_sets``: one per update: the network, where the new data came from (``source``:
  ``layer:SLUG`` or ``file:NAME``; for a layer its id and the version that was read), the
  area it covers (nothing is said of segments outside it), the tolerances the matching used,
  the counts per outcome, who made it and when, and ``status`` (``open``; ``reverted`` once
  undone as a whole).
- ``proposed_changes``: one row per proposal: ``kind`` ``moved`` (``geom`` the proposed line),
  ``new`` (``geom`` the new road, ``attributes`` from the source) or ``missing`` (``geom``
  the segment's line when proposed); the segment and its version when proposed (a segment
  edited since is not changed by an accept), ``edited`` when a person had created or edited
  it (never accepted in bulk), ``status`` proposed / accepted / rejected / reverted, who
  decided and when, and ``result_segment``: the segment an accepted ``new`` created.

Nothing here is routed or drawn as the network: routing sees a change once accepted, when it
is a normal edit of ``road_segments`` with a history row naming the change set.

Revision ID: 0013_change_sets
Revises: 0012_elevation_layers
Create Date: 2026-11-29
"""

import sqlalchemy as sa
from alembic import op
from geoalchemy2 import Geometry
from sqlalchemy.dialects.postgresql import JSONB

revision = "0013_change_sets"
down_revision = "0012_elevation_layers"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "change_sets",
        sa.Column("id", sa.BigInteger, primary_key=True),
        sa.Column("network_id", sa.Integer, sa.ForeignKey("networks.id", ondelete="CASCADE"),
                  nullable=False, index=True),
        sa.Column("source", sa.Text, nullable=False),
        sa.Column("layer_id", sa.Integer, sa.ForeignKey("layers.id", ondelete="SET NULL")),
        sa.Column("layer_version", sa.Integer),
        sa.Column("coverage", Geometry("GEOMETRY", srid=4326, spatial_index=False)),
        sa.Column("tolerances", JSONB, nullable=False, server_default="{}"),
        sa.Column("counts", JSONB, nullable=False, server_default="{}"),
        sa.Column("status", sa.Text, nullable=False, server_default="open"),
        sa.Column("created_by", sa.Text, nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False,
                  server_default=sa.func.now()),
        sa.CheckConstraint("status IN ('open', 'reverted')", name="change_sets_status_known"),
    )
    op.create_table(
        "proposed_changes",
        sa.Column("id", sa.BigInteger, primary_key=True),
        sa.Column("change_set_id", sa.BigInteger,
                  sa.ForeignKey("change_sets.id", ondelete="CASCADE"), nullable=False,
                  index=True),
        sa.Column("kind", sa.Text, nullable=False),
        sa.Column("segment_id", sa.BigInteger),
        sa.Column("segment_version", sa.Integer),
        sa.Column("edited", sa.Boolean, nullable=False, server_default="false"),
        sa.Column("geom", Geometry("LINESTRING", srid=4326), nullable=False),
        sa.Column("attributes", JSONB),
        sa.Column("detail", JSONB, nullable=False, server_default="{}"),
        sa.Column("status", sa.Text, nullable=False, server_default="proposed"),
        sa.Column("decided_by", sa.Text),
        sa.Column("decided_at", sa.DateTime(timezone=True)),
        sa.Column("result_segment", sa.BigInteger),
        sa.CheckConstraint("kind IN ('moved', 'new', 'missing')",
                           name="proposed_changes_kind_known"),
        sa.CheckConstraint("status IN ('proposed', 'accepted', 'rejected', 'reverted')",
                           name="proposed_changes_status_known"),
    )


def downgrade() -> None:
    op.drop_table("proposed_changes")
    op.drop_table("change_sets")
