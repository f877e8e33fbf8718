"""What editing from standard clients (OGC API Features Part 4, QGIS) needs in the schema, and
the raster store the database's files live in.

- ``segment_edits.conditional``: whether the client named the version it edited
  (``If-Match``). QGIS never sends ``If-Match``; with ``UGVMAP_IF_MATCH=optional`` its writes
  are accepted and recorded with ``conditional = false``, the overwritten version in
  ``version_from`` and its values in ``old``, so nothing is lost and a revert undoes it.
- Nodes become editable features like segments: ``road_nodes.version`` (their ETag),
  ``updated_at``/``updated_by``, and their own history, ``node_edits`` (same columns as
  ``segment_edits``).
- ``raster_store``: the one row naming where this database's COGs are (the store root its
  relative references are keys of), recorded by the first raster ingest. A process configured
  with another store (run from another folder with another ``.data``, another
  ``UGVMAP_RASTER_STORE``) is refused at ingest with both locations named, and ``/readyz``
  says so, instead of registering layers whose files no server finds.

Revision ID: 0009_part4_editing
Revises: 0008_extraction_review
Create Date: 2026-11-25
"""

import sqlalchemy as sa
from alembic import op
from sqlalchemy.dialects.postgresql import JSONB

revision = "0009_part4_editing"
down_revision = "0008_extraction_review"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("segment_edits", sa.Column("conditional", sa.Boolean, nullable=False,
                                             server_default="true"))
    op.add_column("road_nodes", sa.Column("version", sa.Integer, nullable=False,
                                          server_default="1"))
    op.add_column("road_nodes", sa.Column("updated_at", sa.DateTime(timezone=True),
                                          nullable=False, server_default=sa.func.now()))
    op.add_column("road_nodes", sa.Column("updated_by", sa.Text))
    op.create_check_constraint("road_nodes_version_pos", "road_nodes", "version >= 1")
    op.create_table(
        "node_edits",
        sa.Column("id", sa.BigInteger, primary_key=True),
        sa.Column("network_id", sa.Integer,
                  sa.ForeignKey("networks.id", ondelete="CASCADE"), nullable=False, index=True),
        sa.Column("node_id", sa.BigInteger, nullable=False, index=True),
        sa.Column("action", sa.Text, nullable=False, server_default="update"),
        sa.Column("version_from", sa.Integer),
        sa.Column("version_to", sa.Integer),
        sa.Column("edited_by", sa.Text, nullable=False),
        sa.Column("edited_at", sa.DateTime(timezone=True), nullable=False,
                  server_default=sa.func.now()),
        sa.Column("conditional", sa.Boolean, nullable=False, server_default="true"),
        sa.Column("old", JSONB),
        sa.Column("new", JSONB),
    )
    op.create_table(
        "raster_store",
        sa.Column("id", sa.Boolean, primary_key=True, server_default="true"),
        sa.Column("root", sa.Text, nullable=False),
        sa.Column("recorded_at", sa.DateTime(timezone=True), nullable=False,
                  server_default=sa.func.now()),
        sa.CheckConstraint("id", name="raster_store_one_row"),
    )


def downgrade() -> None:
    op.drop_table("raster_store")
    op.drop_table("node_edits")
    op.drop_constraint("road_nodes_version_pos", "road_nodes")
    for column in ("updated_by", "updated_at", "version"):
        op.drop_column("road_nodes", column)
    op.drop_column("segment_edits", "conditional")
