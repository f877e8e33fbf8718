"""The first migration creates the catalogue and network schema with its guarantees."""

from __future__ import annotations

import uuid

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import create_engine, inspect, text
from sqlalchemy.exc import IntegrityError

from app.db import migrate
from app.db.models import Base
from testkit.scratch import scratch_database

TABLES = {"layers", "raster_sources", "networks", "road_nodes", "road_segments",
          "segment_edits", "ingest_jobs", "api_tokens"}
SPATIAL = {("layers", "bounds"), ("raster_sources", "footprint"), ("road_nodes", "geom"),
           ("road_segments", "geom")}


def test_tables_and_gist_indexes_exist(database_url: str) -> None:
    engine = create_engine(database_url)
    with engine.connect() as conn:
        assert set(inspect(conn).get_table_names()) >= TABLES
        rows = conn.execute(text(
            "SELECT t.relname, a.attname FROM pg_index i "
            "JOIN pg_class c ON c.oid = i.indexrelid JOIN pg_class t ON t.oid = i.indrelid "
            "JOIN pg_am am ON am.oid = c.relam "
            "JOIN pg_attribute a ON a.attrelid = t.oid AND a.attnum = ANY(i.indkey) "
            "WHERE am.amname = 'gist'")).all()
        assert {(r[0], r[1]) for r in rows} >= SPATIAL
        srids = dict(conn.execute(text(
            "SELECT f_table_name || '.' || f_geometry_column, srid FROM geometry_columns")).all())
    assert srids["raster_sources.footprint"] == 3857
    assert srids["road_segments.geom"] == 4326
    engine.dispose()


def test_models_match_migrations(database_url: str) -> None:
    """The ORM models and the migrated schema must not drift apart."""
    engine = create_engine(database_url)
    with engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn, opts={
            "compare_type": True,
            "include_object": lambda o, n, t, r, c: not (t == "table" and r and c is None),
        }), Base.metadata)
    engine.dispose()
    assert diff == []


def _network_with_nodes(conn) -> tuple[int, int, int]:
    net = conn.execute(text("INSERT INTO networks (name) VALUES (:n) RETURNING id"),
                       {"n": f"net-{uuid.uuid4().hex[:8]}"}).scalar_one()
    a, b = (conn.execute(text(
        "INSERT INTO road_nodes (network_id, geom) "
        "VALUES (:net, ST_SetSRID(ST_MakePoint(:x, 0), 4326)) RETURNING id"),
        {"net": net, "x": x}).scalar_one() for x in (0.0, 0.001))
    return net, a, b


SEGMENT_SQL = (
    "INSERT INTO road_segments (network_id, source_node, target_node, geom, length_m, "
    "lanes_forward, speed_limit_kph, oneway) VALUES (:net, :a, :b, "
    "ST_GeomFromText('LINESTRING(0 0, 0.001 0)', 4326), 111.3, :lanes, :speed, :oneway)"
)


@pytest.mark.parametrize(
    ("lanes", "speed", "oneway"),
    [(-1, 50, "none"), (2, 0, "none"), (2, 900, "none"), (2, 50, "sideways")],
    ids=["negative-lanes", "zero-speed", "absurd-speed", "unknown-oneway"],
)
def test_constraints_reject_bad_segments(database_url: str, lanes: int, speed: float,
                                         oneway: str) -> None:
    engine = create_engine(database_url)
    with engine.begin() as conn:
        net, a, b = _network_with_nodes(conn)
    with pytest.raises(IntegrityError), engine.begin() as conn:
        conn.execute(text(SEGMENT_SQL),
                     {"net": net, "a": a, "b": b, "lanes": lanes, "speed": speed, "oneway": oneway})
    with engine.connect() as conn:
        count = conn.execute(text("SELECT count(*) FROM road_segments WHERE network_id = :n"),
                             {"n": net}).scalar_one()
    assert count == 0
    with engine.begin() as conn:  # the same row with sane values is accepted
        conn.execute(text(SEGMENT_SQL),
                     {"net": net, "a": a, "b": b, "lanes": 2, "speed": 50, "oneway": "none"})
    engine.dispose()


def test_bad_layer_slug_and_geometry_srid_rejected(database_url: str) -> None:
    engine = create_engine(database_url)
    with pytest.raises(IntegrityError), engine.begin() as conn:
        conn.execute(text("INSERT INTO layers (slug, title) VALUES ('Bad Slug; DROP', 't')"))
    with pytest.raises(Exception, match="SRID"), engine.begin() as conn:
        net, a, b = _network_with_nodes(conn)
        conn.execute(text(
            "INSERT INTO road_segments (network_id, source_node, target_node, geom, length_m) "
            "VALUES (:net, :a, :b, ST_GeomFromText('LINESTRING(0 0, 1 1)', 3857), 1)"),
            {"net": net, "a": a, "b": b})
    engine.dispose()


def test_downgrade_and_upgrade_again() -> None:
    """Downgrade to base removes every table; upgrading again restores them (own database)."""
    with scratch_database("ugvmap_mig") as url:
        migrate.downgrade(url, "base")
        engine = create_engine(url)
        with engine.connect() as conn:
            assert not TABLES & set(inspect(conn).get_table_names())
        migrate.upgrade(url)
        with engine.connect() as conn:
            assert set(inspect(conn).get_table_names()) >= TABLES
            assert migrate.current_revision(conn) == migrate.head_revision()
        engine.dispose()
