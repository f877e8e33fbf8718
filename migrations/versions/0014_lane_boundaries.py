"""Lanes from the paint (``ugvmap ingest lanes``, docs/lanes.md): what a segment's markings say.

- ``lane_boundaries``: one row per marking line (or stretch of one) a segment's road has:
  ``geom`` the line (EPSG:4326, like the segments), ``kind`` (``solid``, ``dashed``,
  ``solid_solid``, ``road_edge``, ``stop_line``, ``other``), ``colour``, ``width_m``,
  ``confidence``, where it lies: ``position`` across the road within its lane range (0 = the
  rightmost boundary along the segment's direction; NULL for stop lines and symbols),
  ``offset_m`` (median, + left of the segment) and the stretch of the segment it runs along
  (``station_from_m``/``station_to_m``, metres from the segment's start), and ``source``:
  ``paint`` (found in the imagery) or ``offset`` (no paint there: the lane range's offset
  along the segment, a guess the row says is one). Edited like segments: ``version`` is its
  ETag, history in ``lane_boundary_edits``.
- ``segment_lanes``: the segment's lanes in ranges along it: from/to station, lanes per
  direction, each lane's width and each boundary's offset from right to left across the
  road, and the share of the range's cuts that met every boundary (``confidence``). A lane
  that opens or ends is a new range, not an average.

Both go with their segment (ON DELETE CASCADE); re-running ``ingest lanes`` replaces the rows
of the segments it found paint for. A change to ``lane_boundaries`` bumps the network's version
and notifies (the trigger of ``0002_network_change_notify``), so tile caches and Lanelet2 maps
built from an older version are not served.

Revision ID: 0014_lane_boundaries
Revises: 0013_change_sets
Create Date: 2026-11-29
"""

import sqlalchemy as sa
from alembic import op
from geoalchemy2 import Geometry
from sqlalchemy.dialects.postgresql import ARRAY, JSONB

revision = "0014_lane_boundaries"
down_revision = "0013_change_sets"
branch_labels = None
depends_on = None

KINDS = "('solid', 'dashed', 'solid_solid', 'road_edge', 'stop_line', 'other')"
COLOURS = "('white', 'yellow', 'unknown')"


def _owner() -> list[sa.Column]:
    return [
        sa.Column("id", sa.BigInteger, primary_key=True),
        sa.Column("network_id", sa.Integer, sa.ForeignKey("networks.id", ondelete="CASCADE"),
                  nullable=False, index=True),
        sa.Column("segment_id", sa.BigInteger,
                  sa.ForeignKey("road_segments.id", ondelete="CASCADE"), nullable=False,
                  index=True),
    ]


def upgrade() -> None:
    op.create_table(
        "lane_boundaries", *_owner(),
        sa.Column("geom", Geometry("LINESTRING", srid=4326), nullable=False),
        sa.Column("kind", sa.Text, nullable=False),
        sa.Column("colour", sa.Text, nullable=False, server_default="unknown"),
        sa.Column("width_m", sa.Float),
        sa.Column("confidence", sa.Float),
        sa.Column("position", sa.SmallInteger),
        sa.Column("offset_m", sa.Float),
        sa.Column("station_from_m", sa.Float, nullable=False),
        sa.Column("station_to_m", sa.Float, nullable=False),
        sa.Column("source", sa.Text, nullable=False, server_default="paint"),
        sa.Column("attrs", JSONB, nullable=False, server_default="{}"),
        sa.Column("version", sa.Integer, nullable=False, server_default="1"),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False,
                  server_default=sa.func.now()),
        sa.Column("updated_by", sa.Text),
        sa.CheckConstraint(f"kind IN {KINDS}", name="lane_boundaries_kind_known"),
        sa.CheckConstraint(f"colour IN {COLOURS}", name="lane_boundaries_colour_known"),
        sa.CheckConstraint("source IN ('paint', 'offset')", name="lane_boundaries_source_known"),
        sa.CheckConstraint("confidence IS NULL OR confidence BETWEEN 0 AND 1",
                           name="lane_boundaries_confidence_range"),
        sa.CheckConstraint("width_m IS NULL OR width_m > 0", name="lane_boundaries_width_pos"),
        sa.CheckConstraint("position IS NULL OR position BETWEEN 0 AND 32",
                           name="lane_boundaries_position_range"),
        sa.CheckConstraint("station_from_m <= station_to_m",
                           name="lane_boundaries_stations_ordered"),
        sa.CheckConstraint("version >= 1", name="lane_boundaries_version_pos"),
    )
    op.create_table(
        "segment_lanes", *_owner(),
        sa.Column("station_from_m", sa.Float, nullable=False),
        sa.Column("station_to_m", sa.Float, nullable=False),
        sa.Column("lanes_forward", sa.SmallInteger, nullable=False),
        sa.Column("lanes_backward", sa.SmallInteger, nullable=False),
        sa.Column("widths_m", ARRAY(sa.Float), nullable=False),
        sa.Column("offsets_m", ARRAY(sa.Float), nullable=False),
        sa.Column("confidence", sa.Float),
        sa.Column("source", sa.Text, nullable=False, server_default="paint"),
        sa.CheckConstraint("lanes_forward BETWEEN 0 AND 16 AND lanes_backward BETWEEN 0 AND 16",
                           name="segment_lanes_count_range"),
        sa.CheckConstraint("station_from_m < station_to_m", name="segment_lanes_stations_ordered"),
        sa.CheckConstraint("cardinality(widths_m) = lanes_forward + lanes_backward "
                           "AND cardinality(offsets_m) = cardinality(widths_m) + 1",
                           name="segment_lanes_arrays_match"),
        sa.CheckConstraint("source IN ('paint', 'offset')", name="segment_lanes_source_known"),
    )
    op.create_table(
        "lane_boundary_edits",
        sa.Column("id", sa.BigInteger, primary_key=True),
        sa.Column("network_id", sa.Integer, sa.ForeignKey("networks.id", ondelete="CASCADE"),
                  nullable=False, index=True),
        sa.Column("boundary_id", sa.BigInteger, nullable=False, index=True),
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


    for op_name, refs in (("ins", "NEW TABLE AS new_rows"),
                          ("upd", "OLD TABLE AS old_rows NEW TABLE AS new_rows"),
                          ("del", "OLD TABLE AS old_rows")):
        event = {"ins": "INSERT", "upd": "UPDATE", "del": "DELETE"}[op_name]
        op.execute(f"CREATE TRIGGER lane_boundaries_changed_{op_name} AFTER {event} ON "
                   f"lane_boundaries REFERENCING {refs} "
                   "FOR EACH STATEMENT EXECUTE FUNCTION ugvmap_network_changed()")


def downgrade() -> None:
    op.drop_table("lane_boundary_edits")
    op.drop_table("segment_lanes")
    op.drop_table("lane_boundaries")
