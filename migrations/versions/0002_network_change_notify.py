"""Bump a network's version and NOTIFY on every change to its segments or nodes.

Why a trigger: the routing graph and the MVT tile cache live in every server worker's memory,
and must see an edit the moment it commits no matter which worker or tool made it (PATCH,
import, a psql session). A statement-level trigger with transition tables costs one UPDATE and
one NOTIFY per statement, not per row, so bulk imports stay fast. NOTIFY is delivered only on
commit, so listeners never see uncommitted versions.

Payload on channel ``network_changed``: ``{"network_id", "version", "bbox"}`` where bbox is
``[minlon, minlat, maxlon, maxlat]`` of the changed (old and new) geometries.

Revision ID: 0002_network_change_notify
Revises: 0001
Create Date: 2026-11-22
"""

from alembic import op

revision = "0002_network_change_notify"
down_revision = "0001"
branch_labels = None
depends_on = None

BUMP = """
CREATE FUNCTION ugvmap_network_bump(net_id integer, box geometry) RETURNS void
LANGUAGE plpgsql AS $$
DECLARE v bigint;
BEGIN
    UPDATE networks SET version = version + 1, updated_at = now()
     WHERE id = net_id RETURNING version INTO v;
    IF v IS NULL THEN
        RETURN;  -- the network itself is being deleted
    END IF;
    PERFORM pg_notify('network_changed', json_build_object(
        'network_id', net_id,
        'version', v,
        'bbox', CASE WHEN box IS NULL THEN NULL ELSE json_build_array(
            ST_XMin(box), ST_YMin(box), ST_XMax(box), ST_YMax(box)) END
    )::text);
END $$;
"""

CHANGED = """
CREATE FUNCTION ugvmap_network_changed() RETURNS trigger
LANGUAGE plpgsql AS $$
DECLARE r record;
BEGIN
    IF TG_OP = 'INSERT' THEN
        FOR r IN SELECT network_id, ST_Extent(geom)::geometry AS box
                   FROM new_rows GROUP BY network_id LOOP
            PERFORM ugvmap_network_bump(r.network_id, r.box);
        END LOOP;
    ELSIF TG_OP = 'DELETE' THEN
        FOR r IN SELECT network_id, ST_Extent(geom)::geometry AS box
                   FROM old_rows GROUP BY network_id LOOP
            PERFORM ugvmap_network_bump(r.network_id, r.box);
        END LOOP;
    ELSE
        FOR r IN SELECT network_id, ST_Extent(geom)::geometry AS box FROM (
                     SELECT network_id, geom FROM old_rows
                     UNION ALL SELECT network_id, geom FROM new_rows) AS both_rows
                  GROUP BY network_id LOOP
            PERFORM ugvmap_network_bump(r.network_id, r.box);
        END LOOP;
    END IF;
    RETURN NULL;
END $$;
"""

TABLES = ("road_segments", "road_nodes")


def upgrade() -> None:
    op.execute(BUMP)
    op.execute(CHANGED)
    for table in TABLES:
        op.execute(
            f"CREATE TRIGGER {table}_changed_ins AFTER INSERT ON {table} "
            "REFERENCING NEW TABLE AS new_rows "
            "FOR EACH STATEMENT EXECUTE FUNCTION ugvmap_network_changed()"
        )
        op.execute(
            f"CREATE TRIGGER {table}_changed_upd AFTER UPDATE ON {table} "
            "REFERENCING OLD TABLE AS old_rows NEW TABLE AS new_rows "
            "FOR EACH STATEMENT EXECUTE FUNCTION ugvmap_network_changed()"
        )
        op.execute(
            f"CREATE TRIGGER {table}_changed_del AFTER DELETE ON {table} "
            "REFERENCING OLD TABLE AS old_rows "
            "FOR EACH STATEMENT EXECUTE FUNCTION ugvmap_network_changed()"
        )


def downgrade() -> None:
    for table in TABLES:
        for suffix in ("ins", "upd", "del"):
            op.execute(f"DROP TRIGGER IF EXISTS {table}_changed_{suffix} ON {table}")
    op.execute("DROP FUNCTION IF EXISTS ugvmap_network_changed()")
    op.execute("DROP FUNCTION IF EXISTS ugvmap_network_bump(integer, geometry)")
