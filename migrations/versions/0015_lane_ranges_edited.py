"""A segment's lane ranges edited by a person: ``segment_lanes.source`` may be ``edited``.

``PUT /collections/{network}-segments/items/{id}/lanes`` (app/network/lane_ranges.py) replaces
a segment's ranges as a new version of the segment; its rows say they are a person's, not
read from the paint (``paint``) or guessed (``offset``), and ``ugvmap ingest lanes`` keeps
them.

Revision ID: 0015_lane_ranges_edited
Revises: 0014_lane_boundaries
Create Date: 2026-11-29
"""

from alembic import op

revision = "0015_lane_ranges_edited"
down_revision = "0014_lane_boundaries"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.drop_constraint("segment_lanes_source_known", "segment_lanes", type_="check")
    op.create_check_constraint("segment_lanes_source_known", "segment_lanes",
                               "source IN ('paint', 'offset', 'edited')")


def downgrade() -> None:
    op.execute("UPDATE segment_lanes SET source = 'offset' WHERE source = 'edited'")
    op.drop_constraint("segment_lanes_source_known", "segment_lanes", type_="check")
    op.create_check_constraint("segment_lanes_source_known", "segment_lanes",
                               "source IN ('paint', 'offset')")
