"""Initial catalogue and road-network schema.

Revision ID: 0001
Revises:
Create Date: 2026-11-22
"""

import sqlalchemy as sa
from alembic import op
from geoalchemy2 import Geometry
from sqlalchemy.dialects.postgresql import JSONB

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None

SLUG_RE = "^[a-z0-9][a-z0-9_-]{0,63}$"


def _ts(name: str, nullable: bool = False) -> sa.Column:
    if nullable:
        return sa.Column(name, sa.DateTime(timezone=True), nullable=True)
    return sa.Column(name, sa.DateTime(timezone=True), nullable=False, server_default=sa.func.now())


def _geom(name: str, kind: str, srid: int, nullable: bool = False) -> sa.Column:
    return sa.Column(
        name, Geometry(kind, srid=srid, spatial_index=False), nullable=nullable
    )


def _gist(table: str, column: str) -> None:
    op.create_index(f"idx_{table}_{column}", table, [column], postgresql_using="gist")


def upgrade() -> None:
    op.execute("CREATE EXTENSION IF NOT EXISTS postgis")
    op.create_table(
        "layers",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("slug", sa.Text, nullable=False, unique=True),
        sa.Column("title", sa.Text, nullable=False),
        sa.Column("kind", sa.Text, nullable=False, server_default="orthophoto"),
        sa.Column("crs", sa.Text, nullable=False, server_default="EPSG:3857"),
        sa.Column("resolution_m", sa.Float),
        sa.Column("minzoom", sa.SmallInteger, nullable=False, server_default="0"),
        sa.Column("maxzoom", sa.SmallInteger, nullable=False, server_default="22"),
        _geom("bounds", "POLYGON", 4326, nullable=True),
        sa.Column("attribution", sa.Text),
        sa.Column("overview_uri", sa.Text),
        sa.Column("version", sa.Integer, nullable=False, server_default="1"),
        _ts("created_at"),
        _ts("updated_at"),
        sa.CheckConstraint(f"slug ~ '{SLUG_RE}'", name="layers_slug_format"),
        sa.CheckConstraint("kind IN ('orthophoto', 'ipm-mosaic', 'raster')",
                           name="layers_kind_known"),
        sa.CheckConstraint("minzoom BETWEEN 0 AND 30 AND maxzoom BETWEEN 0 AND 30 "
                           "AND minzoom <= maxzoom", name="layers_zoom_range"),
        sa.CheckConstraint("resolution_m IS NULL OR resolution_m > 0",
                           name="layers_resolution_pos"),
    )
    _gist("layers", "bounds")

    op.create_table(
        "raster_sources",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("layer_id", sa.Integer, sa.ForeignKey("layers.id", ondelete="CASCADE"),
                  nullable=False),
        sa.Column("name", sa.Text, nullable=False),
        sa.Column("uri", sa.Text, nullable=False, unique=True),
        _geom("footprint", "MULTIPOLYGON", 3857),
        _ts("acquired_at", nullable=True),
        _ts("ingested_at"),
        sa.Column("priority", sa.Integer, nullable=False, server_default="0"),
        sa.Column("width", sa.Integer, nullable=False),
        sa.Column("height", sa.Integer, nullable=False),
        sa.Column("band_count", sa.SmallInteger, nullable=False),
        sa.Column("dtype", sa.Text, nullable=False),
        sa.Column("resolution_m", sa.Float, nullable=False),
        sa.Column("checksum", sa.Text),
        sa.Column("meta", JSONB, nullable=False, server_default="{}"),
        sa.CheckConstraint("width > 0 AND height > 0", name="raster_sources_size_pos"),
        sa.CheckConstraint("band_count > 0", name="raster_sources_bands_pos"),
    )
    op.create_index("ix_raster_sources_layer_id", "raster_sources", ["layer_id"])
    _gist("raster_sources", "footprint")

    op.create_table(
        "networks",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("name", sa.Text, nullable=False, unique=True),
        sa.Column("title", sa.Text),
        sa.Column("description", sa.Text),
        sa.Column("version", sa.BigInteger, nullable=False, server_default="0"),
        _ts("created_at"),
        _ts("updated_at"),
        sa.CheckConstraint(f"name ~ '{SLUG_RE}'", name="networks_name_format"),
    )

    op.create_table(
        "road_nodes",
        sa.Column("id", sa.BigInteger, primary_key=True),
        sa.Column("network_id", sa.Integer, sa.ForeignKey("networks.id", ondelete="CASCADE"),
                  nullable=False),
        _geom("geom", "POINT", 4326),
        sa.Column("kind", sa.Text, nullable=False, server_default="node"),
        sa.Column("traffic_light", sa.Boolean, nullable=False, server_default="false"),
        sa.Column("external_id", sa.Text),
        sa.CheckConstraint("kind IN ('junction', 'endpoint', 'node')",
                           name="road_nodes_kind_known"),
    )
    op.create_index("ix_road_nodes_network_id", "road_nodes", ["network_id"])
    _gist("road_nodes", "geom")

    op.create_table(
        "road_segments",
        sa.Column("id", sa.BigInteger, primary_key=True),
        sa.Column("network_id", sa.Integer, sa.ForeignKey("networks.id", ondelete="CASCADE"),
                  nullable=False),
        sa.Column("source_node", sa.BigInteger,
                  sa.ForeignKey("road_nodes.id", ondelete="CASCADE"), nullable=False),
        sa.Column("target_node", sa.BigInteger,
                  sa.ForeignKey("road_nodes.id", ondelete="CASCADE"), nullable=False),
        _geom("geom", "LINESTRING", 4326),
        sa.Column("length_m", sa.Float, nullable=False),
        sa.Column("lanes_forward", sa.SmallInteger, nullable=False, server_default="1"),
        sa.Column("lanes_backward", sa.SmallInteger, nullable=False, server_default="1"),
        sa.Column("speed_limit_kph", sa.Float),
        sa.Column("oneway", sa.Text, nullable=False, server_default="none"),
        sa.Column("road_class", sa.Text, nullable=False, server_default="unclassified"),
        sa.Column("is_junction", sa.Boolean, nullable=False, server_default="false"),
        sa.Column("name", sa.Text),
        sa.Column("surface", sa.Text),
        sa.Column("width_m", sa.Float),
        sa.Column("external_id", sa.Text),
        sa.Column("attrs", JSONB, nullable=False, server_default="{}"),
        sa.Column("version", sa.Integer, nullable=False, server_default="1"),
        _ts("updated_at"),
        sa.Column("updated_by", sa.Text),
        sa.CheckConstraint("lanes_forward BETWEEN 0 AND 16", name="road_segments_lanes_fwd_range"),
        sa.CheckConstraint("lanes_backward BETWEEN 0 AND 16",
                           name="road_segments_lanes_bwd_range"),
        sa.CheckConstraint("speed_limit_kph IS NULL OR speed_limit_kph BETWEEN 1 AND 200",
                           name="road_segments_speed_range"),
        sa.CheckConstraint("oneway IN ('none', 'forward', 'backward')",
                           name="road_segments_oneway_known"),
        sa.CheckConstraint("length_m >= 0", name="road_segments_length_nonneg"),
        sa.CheckConstraint("width_m IS NULL OR width_m > 0", name="road_segments_width_pos"),
        sa.CheckConstraint("version >= 1", name="road_segments_version_pos"),
    )
    for col in ("network_id", "source_node", "target_node"):
        op.create_index(f"ix_road_segments_{col}", "road_segments", [col])
    _gist("road_segments", "geom")

    op.create_table(
        "segment_edits",
        sa.Column("id", sa.BigInteger, primary_key=True),
        sa.Column("network_id", sa.Integer, sa.ForeignKey("networks.id", ondelete="CASCADE"),
                  nullable=False),
        sa.Column("segment_id", sa.BigInteger, nullable=False),
        sa.Column("action", sa.Text, nullable=False, server_default="update"),
        sa.Column("version_from", sa.Integer),
        sa.Column("version_to", sa.Integer),
        sa.Column("edited_by", sa.Text, nullable=False),
        _ts("edited_at"),
        sa.Column("old", JSONB),
        sa.Column("new", JSONB),
    )
    op.create_index("ix_segment_edits_network_id", "segment_edits", ["network_id"])
    op.create_index("ix_segment_edits_segment_id", "segment_edits", ["segment_id"])

    op.create_table(
        "ingest_jobs",
        sa.Column("id", sa.BigInteger, primary_key=True),
        sa.Column("kind", sa.Text, nullable=False),
        sa.Column("target", sa.Text),
        sa.Column("params", JSONB, nullable=False, server_default="{}"),
        sa.Column("status", sa.Text, nullable=False, server_default="queued"),
        sa.Column("progress", sa.Float, nullable=False, server_default="0"),
        sa.Column("message", sa.Text),
        sa.Column("error", sa.Text),
        _ts("created_at"),
        _ts("started_at", nullable=True),
        _ts("finished_at", nullable=True),
        sa.CheckConstraint("status IN ('queued', 'running', 'succeeded', 'failed')",
                           name="ingest_jobs_status_known"),
        sa.CheckConstraint("progress BETWEEN 0 AND 1", name="ingest_jobs_progress_range"),
    )

    op.create_table(
        "api_tokens",
        sa.Column("id", sa.Integer, primary_key=True),
        sa.Column("name", sa.Text, nullable=False),
        sa.Column("token_hash", sa.Text, nullable=False, unique=True),
        sa.Column("role", sa.Text, nullable=False),
        _ts("created_at"),
        _ts("last_used_at", nullable=True),
        _ts("revoked_at", nullable=True),
        sa.CheckConstraint("role IN ('viewer', 'editor', 'admin')", name="api_tokens_role_known"),
    )


def downgrade() -> None:
    for table in ("api_tokens", "ingest_jobs", "segment_edits", "road_segments", "road_nodes",
                  "networks", "raster_sources", "layers"):
        op.drop_table(table)
