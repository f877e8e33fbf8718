"""``ugvmap db``: the embedded PostGIS cluster and schema migrations."""

from __future__ import annotations

import sys

import click

from app.settings import get_settings
from cli.ops import embedded


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
    """Where ugvmap's data is, the same from any folder: the database (the embedded cluster's
    state, or DATABASE_URL), its schema, the data directory, the raster store this process
    uses and the one the database's files are in. Exit 1 if those two differ."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import OperationalError

    from app.db import migrate
    from app.db.session import get_engine
    from app.tiles.store import mismatch, recorded_root, store_root

    settings = get_settings()
    if settings.embedded:
        click.echo(f"database {embedded.status(embedded.cluster_from(settings))}")
    else:
        click.echo("database " + make_url(settings.database_url).render_as_string(
            hide_password=True) + " (DATABASE_URL)")
    click.echo(f"data directory {settings.data_dir}")
    click.echo(f"raster store {store_root()}")
    try:
        with get_engine().connect() as conn:
            revision = migrate.current_revision(conn)
            recorded = recorded_root(conn) if revision == migrate.head_revision() else None
    except OperationalError:
        click.echo("schema unknown: the database does not answer")
        return
    click.echo(f"schema {revision or 'empty (run `ugvmap db upgrade`)'}")
    if recorded is not None and recorded != store_root():
        click.echo(f"Error: {mismatch(recorded, store_root())}", err=True)
        sys.exit(1)
    if recorded is not None:
        click.echo("the database's rasters are in this store")


@db.command("store")
@click.option("--set", "new_root", metavar="ROOT",
              help="Record ROOT (a directory or s3://bucket/prefix) as the store the "
                   "database's files are in, after moving them there.")
def db_store(new_root: str | None) -> None:
    """Show (or, with --set, change) the raster store the database's COGs are in. --set
    checks first that every file the catalogue names is in ROOT."""
    from sqlalchemy import text

    from app.db.session import get_engine
    from app.errors import UserError
    from app.tiles.store import RECORD_ROOT, is_absolute, open_store, recorded_root

    with get_engine().begin() as conn:
        if new_root:
            store = open_store(new_root)
            found: list[str] = list(conn.execute(text(
                "SELECT uri FROM raster_sources UNION SELECT overview_uri FROM layers "
                "WHERE overview_uri IS NOT NULL")).scalars())
            refs = [r for r in found if not is_absolute(r)]
            present = {ref for folder in {r.rpartition("/")[0] for r in refs}
                       for ref in store.refs_under(folder)}
            missing = sorted(set(refs) - present)
            if missing:
                raise UserError(f"{len(missing)} of the catalogue's {len(refs)} files are not "
                                f"in {store.root}, e.g. {missing[0]}; move them there first")
            conn.execute(text(RECORD_ROOT), {"root": store.root})
        click.echo(recorded_root(conn) or "no raster store recorded yet (no ingest so far)")


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
