"""The ``ugvmap`` command line: database, ingest jobs, exports and the server.

Each capability registers its commands on the groups defined here (``ingest``, ...), so this
module stays a table of contents.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from app.cli_errors import CliError, UgvmapGroup
from app.db import embedded
from app.settings import get_settings


@click.group(cls=UgvmapGroup, context_settings={"help_option_names": ["-h", "--help"]})
def main() -> None:
    """ugvmap: imagery to map tiles, road network to routes, for unmanned ground vehicles."""


@main.group()
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
    try:
        embedded.start(cluster)
    except embedded.EmbeddedDbError as exc:
        raise CliError(str(exc)) from exc
    click.echo(f"database {embedded.status(cluster)}")


@db.command("stop")
def db_stop() -> None:
    """Stop the embedded cluster (data is kept)."""
    cluster = _cluster()
    try:
        embedded.stop(cluster)
    except embedded.EmbeddedDbError as exc:
        raise CliError(str(exc)) from exc
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


@main.group()
def ingest() -> None:
    """Batch jobs that write rasters and road networks into the store."""


@main.command()
@click.option("--shared-data", type=click.Path(path_type=Path, file_okay=False),
              default=Path("../shared/data"), show_default=True,
              help="Sample data folder; a synthetic town is generated when it is absent.")
def demo(shared_data: Path) -> None:
    """Load the demo layers and networks (idempotent) and print an editor token."""
    from ingest.demo import load_demo

    token = load_demo(shared_data, get_settings().data_dir / "demo-editor-token", click.echo)
    click.echo(f"editor token for the web map: {token}")


@main.command()
@click.option("--host", default="127.0.0.1", show_default=True)
@click.option("--port", default=8000, show_default=True, type=int)
@click.option("--workers", default=1, show_default=True, type=int)
def serve(host: str, port: int, workers: int) -> None:
    """Serve the web map, tiles, features and routes over HTTP."""
    import uvicorn

    from app.logs import logging_config

    settings = get_settings()
    uvicorn.run(
        "app.main:create_app",
        factory=True,
        host=host,
        port=port,
        workers=workers,
        log_config=logging_config(settings.log_level),
        access_log=False,
    )


def _register_capabilities() -> None:
    """Each capability owns its commands; this is the table of contents."""
    from app.network import cli as network_cli
    from app.routing import cli as routing_cli
    from app.tiles import cli as tiles_cli
    from ingest.ipm import cli as ipm_cli
    from ingest.roads import cli as roads_cli

    ingest.add_command(network_cli.ingest_network)
    main.add_command(network_cli.tokens)
    main.add_command(network_cli.export)
    main.add_command(network_cli.network)
    ingest.add_command(tiles_cli.ingest_raster_cmd)
    main.add_command(tiles_cli.layers)
    main.add_command(routing_cli.route)
    main.add_command(roads_cli.extract_roads)
    main.add_command(roads_cli.evaluate_roads)
    ingest.add_command(roads_cli.ingest_roads)
    main.add_command(roads_cli.roads)
    ingest.add_command(ipm_cli.ingest_ipm_cmd)


_register_capabilities()

if __name__ == "__main__":
    main()
