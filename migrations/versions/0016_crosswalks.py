"""Pedestrian crossings from the paint: ``lane_boundaries.kind`` may be ``crosswalk``.

``ugvmap ingest lanes`` joins a zebra's bars into one crossing (ingest/lanes/crossing.py) and
stores it with the segment it crosses like a stop line: ``position`` NULL, ``geom`` the line
across the road through the bars, ``width_m`` how far the crossing reaches along the road.
The Lanelet2 export draws it as a ``crosswalk`` lanelet.

Revision ID: 0016_crosswalks
Revises: 0015_lane_ranges_edited
Create Date: 2026-11-29
"""

from alembic import op

revision = "0016_crosswalks"
down_revision = "0015_lane_ranges_edited"
branch_labels = None
depends_on = None

KINDS = "'solid', 'dashed', 'solid_solid', 'road_edge', 'stop_line', 'other'"


def upgrade() -> None:
    op.drop_constraint("lane_boundaries_kind_known", "lane_boundaries", type_="check")
    op.create_check_constraint("lane_boundaries_kind_known", "lane_boundaries",
                               f"kind IN ({KINDS}, 'crosswalk')")


def downgrade() -> None:
    op.execute("UPDATE lane_boundaries SET kind = 'other' WHERE kind = 'crosswalk'")
    op.drop_constraint("lane_boundaries_kind_known", "lane_boundaries", type_="check")
    op.create_check_constraint("lane_boundaries_kind_known", "lane_boundaries",
                               f"kind IN ({KINDS})")
