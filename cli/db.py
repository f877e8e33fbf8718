"""``ugvmap db``: the embedded PostGIS cluster and schema migrations."""

from __future__ import annotations

import sys

import click

from app.db import embedded
from app.settings import get_settings


@click.group("db")
def db() -> None:
    """Local PostGIS cluster and schema migrations."""


def _cluster() -> embedded.Cluster:
    settings = get_settings()
    if not settings.embedded:
        click.echo("DATABASE_URL is set: using that database, no local cluster to manage.")
        sys.exit(0)
    return embedded.cluster_from(settings)


@db.command("start")
def db_start() -> None:
    """Initialise (first time) and start the embedded PostGIS cluster under .data/postgres."""
    cluster = _cluster()
    embedded.start(cluster)  # EmbeddedDbError is a UserError: one line from cli.main
    click.echo(f"database {embedded.status(cluster)}")


@db.command("stop")
def db_stop() -> None:
    """Stop the embedded cluster (data is kept)."""
    cluster = _cluster()
    embedded.stop(cluster)
    click.echo(f"database {embedded.status(cluster)}")


@db.command("status")
def db_status() -> None:
    """Say whether the embedded cluster is running."""
    click.echo(f"database {embedded.status(_cluster())}")


@db.command("upgrade")
@click.argument("revision", default="head")
def db_upgrade(revision: str) -> None:
    """Migrate the schema to REVISION (default: head)."""
    from app.db import migrate

    migrate.upgrade(get_settings().database_url, revision)
    click.echo(f"schema at {revision}")


@db.command("downgrade")
@click.argument("revision")
def db_downgrade(revision: str) -> None:
    """Migrate the schema down to REVISION (``base`` removes every table)."""
    from app.db import migrate

    migrate.downgrade(get_settings().database_url, revision)
    click.echo(f"schema at {revision}")
