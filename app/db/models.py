"""SQLAlchemy models of the catalogue (layers, sources, jobs, tokens) and the road network.

The Alembic migrations are the source of truth for the schema; these models mirror them and a
test compares the two so they cannot drift apart. Geometry SRIDs: raster footprints are stored
in EPSG:3857 (the tile grid they are queried against); the road network is stored in EPSG:4326
(what OGC API Features, GeoJSON and route clients speak), with lengths from geography.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from geoalchemy2 import Geometry
from sqlalchemy import (
    BigInteger,
    Boolean,
    CheckConstraint,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    SmallInteger,
    Text,
    func,
)
from sqlalchemy.dialects.postgresql import JSONB
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

SLUG_RE = "^[a-z0-9][a-z0-9_-]{0,63}$"
LAYER_KINDS = ("orthophoto", "ipm-mosaic", "raster", "elevation")
NODE_KINDS = ("junction", "endpoint", "node")
ONEWAY_VALUES = ("none", "forward", "backward")
JOB_STATUSES = ("queued", "running", "succeeded", "failed")  # of jobs and of their parts
TOKEN_ROLES = ("viewer", "editor", "admin")
LABEL_KINDS = ("road", "not_road")  # of a layer's labels
LANE_KINDS = ("solid", "dashed", "solid_solid", "road_edge", "stop_line", "crosswalk",
              "other")
LANE_COLOURS = ("white", "yellow", "unknown")
LANE_SOURCES = ("paint", "offset")  # of lane boundaries (migration 0014)


class Base(DeclarativeBase):
    """Declarative base: the models describe the schema the migrations create (tests compare the
    two)."""
    pass


def _now() -> Any:
    return mapped_column(DateTime(timezone=True), nullable=False, server_default=func.now())


class Layer(Base):
    """A raster layer: what tiles and TileJSON are served under; ``version`` changes on every ingest
    so ETags and caches follow it."""
    __tablename__ = "layers"
    __table_args__ = (
        CheckConstraint(f"slug ~ '{SLUG_RE}'", name="layers_slug_format"),
        CheckConstraint(f"kind IN {LAYER_KINDS}", name="layers_kind_known"),
        CheckConstraint("minzoom BETWEEN 0 AND 30 AND maxzoom BETWEEN 0 AND 30 "
                        "AND minzoom <= maxzoom", name="layers_zoom_range"),
        CheckConstraint("resolution_m IS NULL OR resolution_m > 0", name="layers_resolution_pos"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    slug: Mapped[str] = mapped_column(Text, unique=True, nullable=False)
    title: Mapped[str] = mapped_column(Text, nullable=False)
    kind: Mapped[str] = mapped_column(Text, nullable=False, server_default="orthophoto")
    crs: Mapped[str] = mapped_column(Text, nullable=False, server_default="EPSG:3857")
    resolution_m: Mapped[float | None] = mapped_column(Float)
    minzoom: Mapped[int] = mapped_column(SmallInteger, nullable=False, server_default="0")
    maxzoom: Mapped[int] = mapped_column(SmallInteger, nullable=False, server_default="22")
    bounds: Mapped[Any] = mapped_column(
        Geometry("POLYGON", srid=4326, spatial_index=True), nullable=True
    )
    attribution: Mapped[str | None] = mapped_column(Text)
    overview_uri: Mapped[str | None] = mapped_column(Text)
    version: Mapped[int] = mapped_column(Integer, nullable=False, server_default="1")
    created_at: Mapped[datetime] = _now()
    updated_at: Mapped[datetime] = _now()


class LayerTrajectory(Base):
    """The path a vehicle drove while recording an ``ipm-mosaic`` layer (migration 0008): a road
    sample for extraction that needs no hand labels."""
    __tablename__ = "layer_trajectories"

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    layer_id: Mapped[int] = mapped_column(
        ForeignKey("layers.id", ondelete="CASCADE"), nullable=False, index=True
    )
    name: Mapped[str] = mapped_column(Text, nullable=False)
    geom: Mapped[Any] = mapped_column(
        Geometry("LINESTRING", srid=4326, spatial_index=True), nullable=False
    )
    meta: Mapped[dict[str, Any]] = mapped_column(JSONB, nullable=False, server_default="{}")
    created_at: Mapped[datetime] = _now()


class LayerLabel(Base):
    """A person's label on a raster layer (migration 0010): a road line, a not-road line or a
    not-road area, which every later road extraction of the layer learns from."""
    __tablename__ = "layer_labels"
    __table_args__ = (
        CheckConstraint(f"label IN {LABEL_KINDS}", name="layer_labels_label_known"),
        CheckConstraint("GeometryType(geom) = 'LINESTRING' OR "
                        "(label = 'not_road' AND GeometryType(geom) = 'POLYGON')",
                        name="layer_labels_geometry_type"),
    )

    id: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    layer_id: Mapped[int] = mapped_column(
        ForeignKey("layers.id", ondelete="CASCADE"), nullable=False, index=True
    )
    label: Mapped[str] = mapped_column(Text, nullable=False)
    geom: Mapped[Any] = mapped_column(
        Geometry("GEOMETRY", srid=4326, spatial_index=True), nullable=False
    )
    created_by: Mapped[str] = mapped_column(Text, nullable=False)
    created_at: Mapped[datetime] = _now()


class RasterSource(Base):
    """One COG of a layer, with the footprint tiles are matched against and its paint priority."""
    __tablename__ = "raster_sources"
    __table_args__ = (
        CheckConstraint("width > 0 AND height > 0", name="raster_sources_size_pos"),
        CheckConstraint("band_count > 0", name="raster_sources_bands_pos"),
    )

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    layer_id: Mapped[int] = mapped_column(
        ForeignKey("layers.id", ondelete="CASCADE"), nullable=False, index=True
    )
    name: Mapped[str] = mapped_column(Text, nullable=False)
    uri: Mapped[str] = mapped_column(Text, nullable=False, unique=True)
    footprint: Mapped[Any] = mapped_column(
        Geometry("MULTIPOLYGON", srid=3857, spatial_index=True), nullable=False
    )
    acquired_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    ingested_at: Mapped[datetime] = _now()
    priority: Mapped[int] = mapped_column(Integer, nullable=False, server_default="0")
    width: Mapped[int] = mapped_column(Integer, nullable=False)
    height: Mapped[int] = mapped_column(Integer, nullable=False)
    band_count: Mapped[int] = mapped_column(SmallInteger, nullable=False)
    dtype: Mapped[str] = mapped_column(Text, nullable=False)
    resolution_m: Mapped[float] = mapped_column(Float, nullable=False)
    checksum: Mapped[str | None] = mapped_column(Text)
    meta: Mapped[dict[str, Any]] = mapped_column(JSONB, nullable=False, server_default="{}")


class Network(Base):
    """A road network; ``version`` grows with every committed change, which routing and tile caches
    compare against."""
    __tablename__ = "networks"
    __table_args__ = (CheckConstraint(f"name ~ '{SLUG_RE}'", name="networks_name_format"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(Text, unique=True, nullable=False)
    title: Mapped[str | None] = mapped_column(Text)
    description: Mapped[str | None] = mapped_column(Text)
    version: Mapped[int] = mapped_column(BigInteger, nullable=False, server_default="0")
    settings: Mapped[dict[str, Any]] = mapped_column(JSONB, nullable=False, server_default="{}")
    """Attribute rules extraction applies to this network (migration 0008); {} = defaults."""
    created_at: Mapped[datetime] = _now()
    updated_at: Mapped[datetime] = _now()


class RoadNode(Base):
    """A topology node where segments meet; its kind follows its degree; ``version`` is its
    ETag for optimistic edits (migration 0009)."""
    __tablename__ = "road_nodes"
    __table_args__ = (CheckConstraint(f"kind IN {NODE_KINDS}", name="road_nodes_kind_known"),
                      CheckConstraint("version >= 1", name="road_nodes_version_pos"))

    id: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    network_id: Mapped[int] = mapped_column(
        ForeignKey("networks.id", ondelete="CASCADE"), nullable=False, index=True
    )
    geom: Mapped[Any] = mapped_column(
        Geometry("POINT", srid=4326, spatial_index=True), nullable=False
    )
    kind: Mapped[str] = mapped_column(Text, nullable=False, server_default="node")
    traffic_light: Mapped[bool] = mapped_column(Boolean, nullable=False, server_default="false")
    external_id: Mapped[str | None] = mapped_column(Text)
    version: Mapped[int] = mapped_column(Integer, nullable=False, server_default="1")
    updated_at: Mapped[datetime] = _now()
    updated_by: Mapped[str | None] = mapped_column(Text)


class RoadSegment(Base):
    """A road segment (one-way or two-way) between two nodes, with the attributes the planner needs;
    ``version`` is its ETag for optimistic edits."""
    __tablename__ = "road_segments"
    __table_args__ = (
        CheckConstraint("lanes_forward BETWEEN 0 AND 16", name="road_segments_lanes_fwd_range"),
        CheckConstraint("lanes_backward BETWEEN 0 AND 16", name="road_segments_lanes_bwd_range"),
        CheckConstraint("speed_limit_kph IS NULL OR speed_limit_kph BETWEEN 1 AND 200",
                        name="road_segments_speed_range"),
        CheckConstraint(f"oneway IN {ONEWAY_VALUES}", name="road_segments_oneway_known"),
        CheckConstraint("length_m >= 0", name="road_segments_length_nonneg"),
        CheckConstraint("width_m IS NULL OR width_m > 0", name="road_segments_width_pos"),
        CheckConstraint("version >= 1", name="road_segments_version_pos"),
        CheckConstraint("confidence IS NULL OR confidence BETWEEN 0 AND 1",
                        name="road_segments_confidence_range"),
        Index("ix_road_segments_network_class", "network_id", "road_class"),
    )

    id: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    network_id: Mapped[int] = mapped_column(
        ForeignKey("networks.id", ondelete="CASCADE"), nullable=False, index=True
    )
    source_node: Mapped[int] = mapped_column(
        ForeignKey("road_nodes.id", ondelete="CASCADE"), nullable=False, index=True
    )
    target_node: Mapped[int] = mapped_column(
        ForeignKey("road_nodes.id", ondelete="CASCADE"), nullable=False, index=True
    )
    geom: Mapped[Any] = mapped_column(
        Geometry("LINESTRING", srid=4326, spatial_index=True), nullable=False
    )
    length_m: Mapped[float] = mapped_column(Float, nullable=False)
    lanes_forward: Mapped[int] = mapped_column(SmallInteger, nullable=False, server_default="1")
    lanes_backward: Mapped[int] = mapped_column(SmallInteger, nullable=False, server_default="1")
    speed_limit_kph: Mapped[float | None] = mapped_column(Float)
    oneway: Mapped[str] = mapped_column(Text, nullable=False, server_default="none")
    road_class: Mapped[str] = mapped_column(Text, nullable=False, server_default="unclassified")
    is_junction: Mapped[bool] = mapped_column(Boolean, nullable=False, server_default="false")
    name: Mapped[str | None] = mapped_column(Text)
    surface: Mapped[str | None] = mapped_column(Text)
    width_m: Mapped[float | None] = mapped_column(Float)
    external_id: Mapped[str | None] = mapped_column(Text)
    attrs: Mapped[dict[str, Any]] = mapped_column(JSONB, nullable=False, server_default="{}")
    confidence: Mapped[float | None] = mapped_column(Float)
    """How sure road extraction was of this segment (0..1); NULL when not extracted."""
    version: Mapped[int] = mapped_column(Integer, nullable=False, server_default="1")
    updated_at: Mapped[datetime] = _now()
    updated_by: Mapped[str | None] = mapped_column(Text)


class RoadOverview(Base):
    """Main roads merged per class and 20 km cell, for low-zoom tiles (migration 0003)."""

    __tablename__ = "road_overview"

    network_id: Mapped[int] = mapped_column(
        ForeignKey("networks.id", ondelete="CASCADE"), primary_key=True
    )
    road_class: Mapped[str] = mapped_column(Text, primary_key=True)
    cx: Mapped[int] = mapped_column(Integer, primary_key=True)
    cy: Mapped[int] = mapped_column(Integer, primary_key=True)
    segments: Mapped[int] = mapped_column(Integer, nullable=False)
    geom: Mapped[Any] = mapped_column(
        Geometry("GEOMETRY", srid=3857, spatial_index=True), nullable=False
    )


class EditRow:
    """The columns every edit history row has: which network, what was done, between which
    versions, by whom and when, and the old and new values, so history and revert need no
    other source."""

    id: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    network_id: Mapped[int] = mapped_column(
        ForeignKey("networks.id", ondelete="CASCADE"), nullable=False, index=True
    )
    action: Mapped[str] = mapped_column(Text, nullable=False, server_default="update")
    version_from: Mapped[int | None] = mapped_column(Integer)
    version_to: Mapped[int | None] = mapped_column(Integer)
    edited_by: Mapped[str] = mapped_column(Text, nullable=False)
    edited_at: Mapped[datetime] = _now()
    conditional: Mapped[bool] = mapped_column(Boolean, nullable=False, server_default="true")
    """False when the client named no version (no ``If-Match``, allowed by
    ``UGVMAP_IF_MATCH=optional``): it overwrote whatever was current, kept in ``old``."""
    old: Mapped[dict[str, Any] | None] = mapped_column(JSONB)
    new: Mapped[dict[str, Any] | None] = mapped_column(JSONB)


class SegmentEdit(EditRow, Base):
    """One edit of a segment."""
    __tablename__ = "segment_edits"

    segment_id: Mapped[int] = mapped_column(BigInteger, nullable=False, index=True)


class NodeEdit(EditRow, Base):
    """One edit of a node (migration 0009)."""
    __tablename__ = "node_edits"

    node_id: Mapped[int] = mapped_column(BigInteger, nullable=False, index=True)


class RasterStoreRoot(Base):
    """The raster store this database's relative COG references are keys of: one row,
    recorded by the first ingest (migration 0009), so a process configured with another store
    is refused instead of registering files no server finds."""
    __tablename__ = "raster_store"
    __table_args__ = (CheckConstraint("id", name="raster_store_one_row"),)

    id: Mapped[bool] = mapped_column(Boolean, primary_key=True, server_default="true")
    root: Mapped[str] = mapped_column(Text, nullable=False)
    recorded_at: Mapped[datetime] = _now()


class IngestJob(Base):
    """A batch job's row, written on its own connection so progress shows before the job commits."""
    __tablename__ = "ingest_jobs"
    __table_args__ = (
        CheckConstraint(f"status IN {JOB_STATUSES}", name="ingest_jobs_status_known"),
        CheckConstraint("progress BETWEEN 0 AND 1", name="ingest_jobs_progress_range"),
    )

    id: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    kind: Mapped[str] = mapped_column(Text, nullable=False)
    target: Mapped[str | None] = mapped_column(Text)
    params: Mapped[dict[str, Any]] = mapped_column(JSONB, nullable=False, server_default="{}")
    status: Mapped[str] = mapped_column(Text, nullable=False, server_default="queued",
                                        index=True)
    progress: Mapped[float] = mapped_column(Float, nullable=False, server_default="0")
    message: Mapped[str | None] = mapped_column(Text)
    error: Mapped[str | None] = mapped_column(Text)
    created_at: Mapped[datetime] = _now()
    started_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    # The running process renews this lease; when it runs out the process is dead (0005).
    heartbeat_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    # Runs on `ugvmap worker` processes (retried by the queue) rather than in its caller.
    queued: Mapped[bool] = mapped_column(Boolean, nullable=False, server_default="false")
    worker: Mapped[str | None] = mapped_column(Text)  # host:pid that last worked on it


class IngestJobPart(Base):
    """One source of a fanned-out job: its own task writes it, the last one to finish queues
    the registration of them all (migration 0005)."""
    __tablename__ = "ingest_job_parts"
    __table_args__ = (
        CheckConstraint(f"status IN {JOB_STATUSES}", name="ingest_job_parts_status_known"),
    )

    job_id: Mapped[int] = mapped_column(
        ForeignKey("ingest_jobs.id", ondelete="CASCADE"), primary_key=True)
    part: Mapped[int] = mapped_column(Integer, primary_key=True)
    source: Mapped[str] = mapped_column(Text, nullable=False)
    status: Mapped[str] = mapped_column(Text, nullable=False, server_default="queued")
    attempts: Mapped[int] = mapped_column(Integer, nullable=False, server_default="0")
    worker: Mapped[str | None] = mapped_column(Text)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSONB)
    updated_at: Mapped[datetime] = _now()


class RoadPreview(Base):
    """The roads a ``road-preview`` job extracted from a window of a layer, stored only when
    the layer was still at ``layer_version`` when it finished (migration 0011): accepting it
    into a network compares that version with the layer's."""
    __tablename__ = "road_previews"

    job_id: Mapped[int] = mapped_column(
        ForeignKey("ingest_jobs.id", ondelete="CASCADE"), primary_key=True)
    layer_id: Mapped[int] = mapped_column(
        ForeignKey("layers.id", ondelete="CASCADE"), nullable=False, index=True)
    layer_version: Mapped[int] = mapped_column(Integer, nullable=False)
    bbox: Mapped[Any] = mapped_column(
        Geometry("POLYGON", srid=4326, spatial_index=False), nullable=False)
    result: Mapped[dict[str, Any]] = mapped_column(JSONB, nullable=False)
    created_at: Mapped[datetime] = _now()


class ApiToken(Base):
    """An API token; only its hash is stored, so a database leak does not leak tokens."""
    __tablename__ = "api_tokens"
    __table_args__ = (CheckConstraint(f"role IN {TOKEN_ROLES}", name="api_tokens_role_known"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(Text, nullable=False)
    token_hash: Mapped[str] = mapped_column(Text, nullable=False, unique=True)
    role: Mapped[str] = mapped_column(Text, nullable=False)
    created_at: Mapped[datetime] = _now()
    last_used_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    revoked_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
    expires_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True))
