"""Labels a map team gives a raster layer, which every later road extraction of it learns from.

- ``layer_labels``: one stroke or area per row, in lon/lat: ``road`` lines (along a road the
  model missed) and ``not_road`` lines (along something it wrongly drew) or polygons (an
  area with no road in it), with who drew it and when. The web map's Teach tool and
  ``ugvmap layers labels`` write them; ``ugvmap ingest roads --layer`` and the roads job read
  them as a training sample. They belong to the layer: deleting it deletes them.

Revision ID: 0010_layer_labels
Revises: 0009_part4_editing
Create Date: 2026-11-28
"""

import sqlalchemy as sa
from alembic import op
from geoalchemy2 import Geometry

revision = "0010_layer_labels"
down_revision = "0009_part4_editing"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "layer_labels",
        sa.Column("id", sa.BigInteger, primary_key=True),
        sa.Column("layer_id", sa.Integer, sa.ForeignKey("layers.id", ondelete="CASCADE"),
                  nullable=False, index=True),
        sa.Column("label", sa.Text, nullable=False),
        sa.Column("geom", Geometry("GEOMETRY", srid=4326, spatial_index=False),
                  nullable=False),
        sa.Column("created_by", sa.Text, nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False,
                  server_default=sa.func.now()),
        sa.CheckConstraint("label IN ('road', 'not_road')", name="layer_labels_label_known"),
        sa.CheckConstraint(
            "GeometryType(geom) = 'LINESTRING' OR "
            "(label = 'not_road' AND GeometryType(geom) = 'POLYGON')",
            name="layer_labels_geometry_type"),
    )
    op.create_index("idx_layer_labels_geom", "layer_labels", ["geom"], postgresql_using="gist")


def downgrade() -> None:
    op.drop_index("idx_layer_labels_geom", table_name="layer_labels")
    op.drop_table("layer_labels")
