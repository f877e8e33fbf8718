"""Road previews: what the web map's Teach tool shows before anything enters a network.

- ``road_previews``: the result of one ``road-preview`` job (the job's id is the preview's):
  the roads extracted from a window of a raster layer, with their confidence, as a GeoJSON
  FeatureCollection, the layer version the window was read at, the window (lon/lat) and the
  labels the extraction learned from. A row is written only by a preview that finished on
  the layer version it started from, so *accept* can refuse a preview of imagery that changed
  since (409) by comparing versions. Rows go with their job and with their layer.

Revision ID: 0011_road_previews
Revises: 0010_layer_labels
Create Date: 2026-11-28
"""

import sqlalchemy as sa
from alembic import op
from geoalchemy2 import Geometry
from sqlalchemy.dialects.postgresql import JSONB

revision = "0011_road_previews"
down_revision = "0010_layer_labels"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "road_previews",
        sa.Column("job_id", sa.BigInteger,
                  sa.ForeignKey("ingest_jobs.id", ondelete="CASCADE"), primary_key=True),
        sa.Column("layer_id", sa.Integer, sa.ForeignKey("layers.id", ondelete="CASCADE"),
                  nullable=False, index=True),
        sa.Column("layer_version", sa.Integer, nullable=False),
        sa.Column("bbox", Geometry("POLYGON", srid=4326, spatial_index=False),
                  nullable=False),
        sa.Column("result", JSONB, nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False,
                  server_default=sa.func.now()),
    )


def downgrade() -> None:
    op.drop_table("road_previews")
