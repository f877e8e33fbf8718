"""The ``ugvmap`` command line: database, ingest jobs, exports and the server.

Each capability registers its commands on the groups defined here (``ingest``, ...), so this
module stays a table of contents.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click

from app.db import embedded
from app.settings import get_settings


class CliError(click.ClickException):
    """A user-facing error: printed as one clear line, exit status 1, no traceback."""


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
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
    from sqlalchemy.exc import OperationalError

    from app.db import migrate

    url = get_settings().database_url
    try:
        migrate.upgrade(url, revision)
    except OperationalError as exc:
        raise CliError(f"cannot reach the database ({exc.orig}); `ugvmap db start`?") from exc
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


@ingest.command("raster")
@click.argument("sources", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--layer", "slug", required=True, help="Layer slug (created if new).")
@click.option("--title", help="Human title of the layer.")
@click.option("--kind", default="orthophoto", show_default=True,
              type=click.Choice(["orthophoto", "ipm-mosaic", "raster"]))
@click.option("--crs", help="CRS of world-file images (e.g. EPSG:32633).")
@click.option("--priority", default=0, show_default=True, type=int,
              help="Higher priority sources are drawn over lower ones; ties: newest on top.")
@click.option("--gcps", "gcps_file", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="CSV pixel_x,pixel_y,X,Y[,id] (lon/lat, or in --crs) to georeference SRC.")
@click.option("--gcp-method", default="poly1", show_default=True,
              type=click.Choice(["poly1", "poly2", "tps"]))
def ingest_raster_cmd(sources: tuple[Path, ...], slug: str, title: str | None, kind: str,
                      crs: str | None, priority: int, gcps_file: Path | None,
                      gcp_method: str) -> None:
    """Ingest GeoTIFFs / world-file images / zone mosaics / GCP images into layer SLUG."""
    from ingest.raster.gcps import ingest_with_gcps
    from ingest.raster.job import ingest_raster
    from ingest.raster.sources import SourceError

    options = {"title": title, "kind": kind, "priority": priority}
    try:
        if gcps_file is None:
            report = ingest_raster(list(sources), slug, crs=crs, **options)
        elif len(sources) != 1:
            raise CliError("--gcps georeferences exactly one SRC image")
        else:
            accuracy, report = ingest_with_gcps(sources[0], slug, gcps_file, gcp_method, crs,
                                                **options)
            click.echo(accuracy.table())
    except SourceError as exc:
        raise CliError(str(exc)) from exc
    for src in report.sources:
        click.echo(f"{src.name}: {src.width}x{src.height} px at z{src.zoom} "
                   f"({src.resolution_m:.3f} m/px) -> {src.uri}")
    click.echo(f"layer {report.layer} at version {report.version}")


@main.group()
def layers() -> None:
    """Raster layers in the catalogue."""


@layers.command("list")
def layers_list() -> None:
    """One line per layer: slug, kind, zooms, sources, version."""
    from app.db.session import get_engine
    from app.tiles.catalog import list_layers

    with get_engine().connect() as conn:
        for layer in list_layers(conn):
            click.echo(f"{layer['slug']}\t{layer['kind']}\tz{layer['minzoom']}-{layer['maxzoom']}"
                       f"\t{layer['source_count']} sources\tv{layer['version']}\t{layer['title']}")


@layers.command("show")
@click.argument("slug")
def layers_show(slug: str) -> None:
    """A layer and its sources (last listed is drawn on top)."""
    from app.db.session import get_engine
    from app.tiles.catalog import get_layer

    with get_engine().connect() as conn:
        layer = get_layer(conn, slug)
    if layer is None:
        raise CliError(f"no raster layer {slug!r}")
    for key in ("slug", "title", "kind", "minzoom", "maxzoom", "resolution_m", "bounds",
                "version"):
        click.echo(f"{key}: {layer[key]}")
    for src in layer["sources"]:
        click.echo(f"  source {src['id']}: {src['name']} z{src['zoom']} {src['width']}x"
                   f"{src['height']} priority={src['priority']} georef={src['georef']} "
                   f"ingested {src['ingested_at']:%Y-%m-%d %H:%M:%S} {src['uri']}")


@layers.command("delete")
@click.argument("slug")
def layers_delete(slug: str) -> None:
    """Delete a layer, its catalogue rows and its COG files."""
    from app.db.session import get_engine
    from app.tiles.catalog import delete_layer

    with get_engine().begin() as conn:
        uris = delete_layer(conn, slug)
    if uris is None:
        raise CliError(f"no raster layer {slug!r}")
    for uri in uris:
        Path(uri).unlink(missing_ok=True)
    click.echo(f"deleted layer {slug} ({len(uris)} files)")


def _register_network_commands() -> None:
    from app.network import cli as network_cli

    ingest.add_command(network_cli.ingest_network)
    main.add_command(network_cli.tokens)
    main.add_command(network_cli.export)
    main.add_command(network_cli.network)


_register_network_commands()


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


def _register_routing() -> None:
    from app.routing.cli import route

    main.add_command(route)


_register_routing()


if __name__ == "__main__":
    main()
