"""Elevation layers: ``layers.kind`` may be ``elevation`` (a DSM or DTM: float32 heights in
metres, drawn as hillshade, slope or Terrarium tiles; docs/terrain.md).

Revision ID: 0012_elevation_layers
Revises: 0011_road_previews
Create Date: 2026-11-29
"""

from alembic import op

revision = "0012_elevation_layers"
down_revision = "0011_road_previews"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.drop_constraint("layers_kind_known", "layers", type_="check")
    op.create_check_constraint(
        "layers_kind_known", "layers",
        "kind IN ('orthophoto', 'ipm-mosaic', 'raster', 'elevation')")


def downgrade() -> None:
    op.execute("DELETE FROM layers WHERE kind = 'elevation'")
    op.drop_constraint("layers_kind_known", "layers", type_="check")
    op.create_check_constraint(
        "layers_kind_known", "layers", "kind IN ('orthophoto', 'ipm-mosaic', 'raster')")
