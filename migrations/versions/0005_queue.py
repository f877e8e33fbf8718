"""The job queue: procrastinate's schema, job leases and per-source job parts.

Why here: procrastinate keeps its queue in PostgreSQL tables, functions and triggers that its
own ``schema.sql`` creates. Alembic stays the only way our schema changes, so this revision
applies the SQL shipped in the installed package (pinned in pyproject.toml: a procrastinate
upgrade that changes its schema comes with a new revision applying its migration files) and
drops every ``procrastinate_*`` object on downgrade.

Ours, alongside:
- ``ingest_jobs.heartbeat_at``: the running process renews it (a lease); a row whose lease
  ran out belongs to a dead process and is marked failed instead of staying ``running``.
- ``ingest_jobs.queued``: the job runs on ``ugvmap worker`` processes (the queue retries it
  when a worker dies) rather than in the command that started it.
- ``ingest_jobs.worker``: host and pid of the process that last worked on it (admins only).
- ``ingest_job_parts``: one row per source of a fanned-out job; the last part to finish,
  under the job row's lock, queues the task that registers the layer once.

Revision ID: 0005_queue
Revises: 0003_netscale
Create Date: 2026-12-02
"""

import sqlalchemy as sa
from alembic import op
from procrastinate.schema import SchemaManager
from sqlalchemy.dialects.postgresql import JSONB

revision = "0005_queue"
down_revision = "0003_netscale"
branch_labels = None
depends_on = None

DROP_PROCRASTINATE = r"""
DO $$
DECLARE r record;
BEGIN
    FOR r IN SELECT c.oid::regclass AS t FROM pg_class c
               JOIN pg_namespace n ON n.oid = c.relnamespace
              WHERE n.nspname = current_schema() AND c.relkind = 'r'
                AND c.relname LIKE 'procrastinate\_%' LOOP
        EXECUTE 'DROP TABLE IF EXISTS ' || r.t || ' CASCADE';
    END LOOP;
    FOR r IN SELECT p.oid::regprocedure AS f FROM pg_proc p
               JOIN pg_namespace n ON n.oid = p.pronamespace
              WHERE n.nspname = current_schema() AND p.proname LIKE 'procrastinate\_%' LOOP
        EXECUTE 'DROP FUNCTION IF EXISTS ' || r.f || ' CASCADE';
    END LOOP;
    -- the tables' row types went with them: what is left are the enums and composites
    FOR r IN SELECT t.oid::regtype AS t FROM pg_type t
               JOIN pg_namespace n ON n.oid = t.typnamespace
              WHERE n.nspname = current_schema() AND t.typname LIKE 'procrastinate\_%'
                AND t.typtype IN ('e', 'c') LOOP
        EXECUTE 'DROP TYPE IF EXISTS ' || r.t || ' CASCADE';
    END LOOP;
END $$;
"""

PART_STATUSES = "('queued', 'running', 'succeeded', 'failed')"


def _driver_execute(sql: str) -> None:
    """Run a multi-statement script as is: psycopg sends a query without parameters
    unparsed, so procrastinate's ``%`` and ``:`` need no escaping."""
    op.get_bind().connection.driver_connection.execute(sql)


def upgrade() -> None:
    _driver_execute(SchemaManager.get_schema())
    op.add_column("ingest_jobs", sa.Column("heartbeat_at", sa.DateTime(timezone=True)))
    op.add_column("ingest_jobs", sa.Column("queued", sa.Boolean, nullable=False,
                                           server_default="false"))
    op.add_column("ingest_jobs", sa.Column("worker", sa.Text))
    op.create_index("ix_ingest_jobs_status", "ingest_jobs", ["status"])
    op.create_table(
        "ingest_job_parts",
        sa.Column("job_id", sa.BigInteger,
                  sa.ForeignKey("ingest_jobs.id", ondelete="CASCADE"), primary_key=True),
        sa.Column("part", sa.Integer, primary_key=True),
        sa.Column("source", sa.Text, nullable=False),
        sa.Column("status", sa.Text, nullable=False, server_default="queued"),
        sa.Column("attempts", sa.Integer, nullable=False, server_default="0"),
        sa.Column("worker", sa.Text),
        sa.Column("result", JSONB),
        sa.Column("updated_at", sa.DateTime(timezone=True), nullable=False,
                  server_default=sa.func.now()),
        sa.CheckConstraint(f"status IN {PART_STATUSES}", name="ingest_job_parts_status_known"),
    )


def downgrade() -> None:
    op.drop_table("ingest_job_parts")
    op.drop_index("ix_ingest_jobs_status", "ingest_jobs")
    for column in ("worker", "queued", "heartbeat_at"):
        op.drop_column("ingest_jobs", column)
    _driver_execute(DROP_PROCRASTINATE)
