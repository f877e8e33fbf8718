"""What road extraction hands over: a confidence per segment, per-network attribute rules, and
the trajectories of the vehicle's own drives.

- ``road_segments.confidence`` (0..1, NULL for roads that were not extracted from imagery):
  how sure the extraction was of a segment (e.g. mean road probability along it), so a map
  team reviews the doubtful ones first.
- ``networks.settings`` (JSON): the rules an extraction applies when it writes attributes
  (speed per road class, lane width, ...), overridable per network; empty = the defaults.
- ``layer_trajectories``: the path a vehicle drove while recording an ``ipm-mosaic`` layer
  (``ugvmap ingest ipm`` knows it from the poses). Road extraction on the layer uses it as a
  road sample that needs no hand labels (the vehicle drove there).

Revision ID: 0008_extraction_review
Revises: 0007_store_uris
Create Date: 2026-11-24
"""

import sqlalchemy as sa
from alembic import op
from geoalchemy2 import Geometry
from sqlalchemy.dialects.postgresql import JSONB

revision = "0008_extraction_review"
down_revision = "0007_store_uris"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("road_segments", sa.Column("confidence", sa.Float))
    op.create_check_constraint("road_segments_confidence_range", "road_segments",
                               "confidence IS NULL OR confidence BETWEEN 0 AND 1")
    op.add_column("networks", sa.Column("settings", JSONB, nullable=False,
                                        server_default="{}"))
    op.create_table(
        "layer_trajectories",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("layer_id", sa.Integer, sa.ForeignKey("layers.id", ondelete="CASCADE"),
                  nullable=False, index=True),
        sa.Column("name", sa.Text, nullable=False),
        sa.Column("geom", Geometry("LINESTRING", srid=4326, spatial_index=False),
                  nullable=False),
        sa.Column("meta", JSONB, nullable=False, server_default="{}"),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False,
                  server_default=sa.func.now()),
    )
    op.create_index("idx_layer_trajectories_geom", "layer_trajectories", ["geom"],
                    postgresql_using="gist")


def downgrade() -> None:
    op.drop_index("idx_layer_trajectories_geom", table_name="layer_trajectories")
    op.drop_table("layer_trajectories")
    op.drop_column("networks", "settings")
    op.drop_constraint("road_segments_confidence_range", "road_segments")
    op.drop_column("road_segments", "confidence")
