"""Country-size networks: quiet bulk loads, low-zoom overview lines, a class index.

- ``ugvmap_network_changed()`` (the trigger function of ``0002_network_change_notify``)
  returns at once while the transaction's setting ``ugvmap.bulk_load`` is ``on``. A streamed
  import sets it, writes a million rows in a few statements, and bumps the network version once
  with no bounding box (``ugvmap_network_bump(id, NULL)``: "reload the whole network"), so
  listeners reload once instead of computing and applying the extent of every bulk statement.
  Any other session (PATCH, psql) never sets it and notifies exactly as before.
- ``road_overview``: the main roads (:data:`MAIN_CLASSES`) of each network merged per class
  and 20 km web-mercator cell (by the cell of each segment's first point), simplified to
  19 m (a pixel at zoom 9). Vector tiles below zoom 10 read these few rows instead of every
  main-road segment under the tile. Kept current in the edit's own transaction: a statement
  trigger on ``road_segments`` recomputes the cells meeting the changed main roads (edits of
  other classes skip it); a bulk import refreshes the whole network once
  (``ugvmap_overview_refresh(id, NULL)``).
- ``(network_id, road_class)`` lets tiles at zooms 10-11, which show only some classes, read
  just those rows.

Revision ID: 0003_netscale
Revises: 0002_network_change_notify
Create Date: 2026-11-23
"""

import importlib

import sqlalchemy as sa
from alembic import op
from geoalchemy2 import Geometry

revision = "0003_netscale"
down_revision = "0002_network_change_notify"
branch_labels = None
depends_on = None

_0002 = importlib.import_module("migrations.versions.0002_network_change_notify")
BULK_GUARD = """    IF current_setting('ugvmap.bulk_load', true) = 'on' THEN
        RETURN NULL;  -- a bulk load announces itself once, when it is done
    END IF;
"""
# app/network/tiles.py draws these below zoom 10; keep the two lists equal.
MAIN_CLASSES = ("motorway", "trunk", "primary", "secondary", "tertiary", "motorway_link",
                "trunk_link", "primary_link")
MAIN = "ARRAY[" + ", ".join(f"'{c}'" for c in MAIN_CLASSES) + "]"
CELL_M = 20000
TOLERANCE_M = 19.0

REFRESH = f"""
CREATE FUNCTION ugvmap_overview_refresh(net_id integer, box geometry) RETURNS void
LANGUAGE plpgsql AS $$
DECLARE
    area geometry;
    x0 int := -2147483647; y0 int := -2147483647; x1 int := 2147483647; y1 int := 2147483647;
BEGIN
    IF box IS NOT NULL THEN
        area := ST_Transform(ST_MakeEnvelope(ST_XMin(box), GREATEST(ST_YMin(box), -85),
                                             ST_XMax(box), LEAST(ST_YMax(box), 85), 4326), 3857);
        x0 := floor(ST_XMin(area) / {CELL_M}); x1 := floor(ST_XMax(area) / {CELL_M});
        y0 := floor(ST_YMin(area) / {CELL_M}); y1 := floor(ST_YMax(area) / {CELL_M});
        area := ST_Transform(ST_MakeEnvelope(x0 * {CELL_M} - {CELL_M}, y0 * {CELL_M} - {CELL_M},
                                             (x1 + 2) * {CELL_M}, (y1 + 2) * {CELL_M}, 3857),
                             4326);
    END IF;
    DELETE FROM road_overview
     WHERE network_id = net_id AND cx BETWEEN x0 AND x1 AND cy BETWEEN y0 AND y1;
    INSERT INTO road_overview (network_id, road_class, cx, cy, segments, geom)
    SELECT net_id, road_class, cx, cy, n, g FROM (
        SELECT road_class, cx, cy, count(*) AS n,
               ST_Simplify(ST_LineMerge(ST_Collect(g)), {TOLERANCE_M}) AS g
          FROM (SELECT road_class, ST_Transform(geom, 3857) AS g,
                       floor(ST_X(ST_Transform(ST_StartPoint(geom), 3857)) / {CELL_M})::int AS cx,
                       floor(ST_Y(ST_Transform(ST_StartPoint(geom), 3857)) / {CELL_M})::int AS cy
                  FROM road_segments
                 WHERE network_id = net_id AND road_class = ANY({MAIN})
                   AND (area IS NULL OR geom && area)) AS s
         WHERE cx BETWEEN x0 AND x1 AND cy BETWEEN y0 AND y1
         GROUP BY road_class, cx, cy) AS merged
     WHERE g IS NOT NULL AND NOT ST_IsEmpty(g);
END $$;
"""

OVERVIEW_CHANGED = f"""
CREATE FUNCTION ugvmap_overview_changed() RETURNS trigger
LANGUAGE plpgsql AS $$
DECLARE r record;
BEGIN
{BULK_GUARD}
    IF TG_OP IN ('UPDATE', 'DELETE') THEN
        FOR r IN SELECT network_id, ST_Extent(geom)::geometry AS box FROM old_rows
                  WHERE road_class = ANY({MAIN}) GROUP BY network_id LOOP
            PERFORM ugvmap_overview_refresh(r.network_id, r.box);
        END LOOP;
    END IF;
    IF TG_OP IN ('UPDATE', 'INSERT') THEN
        FOR r IN SELECT network_id, ST_Extent(geom)::geometry AS box FROM new_rows
                  WHERE road_class = ANY({MAIN}) GROUP BY network_id LOOP
            PERFORM ugvmap_overview_refresh(r.network_id, r.box);
        END LOOP;
    END IF;
    RETURN NULL;
END $$;
"""
TRIGGERS = {"ins": "INSERT", "upd": "UPDATE", "del": "DELETE"}


def _changed(guarded: bool) -> str:
    sql = _0002.CHANGED.replace("CREATE FUNCTION", "CREATE OR REPLACE FUNCTION", 1)
    return sql.replace("BEGIN\n", "BEGIN\n" + BULK_GUARD, 1) if guarded else sql


def upgrade() -> None:
    op.execute(_changed(guarded=True))
    op.create_index("ix_road_segments_network_class", "road_segments",
                    ["network_id", "road_class"])
    op.create_table(
        "road_overview",
        sa.Column("network_id", sa.Integer, sa.ForeignKey("networks.id", ondelete="CASCADE"),
                  primary_key=True),
        sa.Column("road_class", sa.Text, primary_key=True),
        sa.Column("cx", sa.Integer, primary_key=True),
        sa.Column("cy", sa.Integer, primary_key=True),
        sa.Column("segments", sa.Integer, nullable=False),
        sa.Column("geom", Geometry("GEOMETRY", srid=3857, spatial_index=False), nullable=False),
    )
    op.create_index("idx_road_overview_geom", "road_overview", ["geom"],
                    postgresql_using="gist")
    op.execute(REFRESH)
    op.execute(OVERVIEW_CHANGED)
    for suffix, event in TRIGGERS.items():
        refs = {"ins": "NEW TABLE AS new_rows", "del": "OLD TABLE AS old_rows",
                "upd": "OLD TABLE AS old_rows NEW TABLE AS new_rows"}[suffix]
        op.execute(f"CREATE TRIGGER road_segments_overview_{suffix} AFTER {event} ON "
                   f"road_segments REFERENCING {refs} FOR EACH STATEMENT "
                   "EXECUTE FUNCTION ugvmap_overview_changed()")
    op.execute("SELECT ugvmap_overview_refresh(id, NULL) FROM networks")


def downgrade() -> None:
    for suffix in TRIGGERS:
        op.execute(f"DROP TRIGGER road_segments_overview_{suffix} ON road_segments")
    op.execute("DROP FUNCTION ugvmap_overview_changed()")
    op.execute("DROP FUNCTION ugvmap_overview_refresh(integer, geometry)")
    op.drop_table("road_overview")
    op.drop_index("ix_road_segments_network_class", "road_segments")
    op.execute(_changed(guarded=False))
