"""The ``ugvmap`` root command: a table of contents of every capability's commands.

Each capability module (``cli.db``, ``cli.network``, ...) defines its commands; this module
only registers them, on the root or on the ``ingest`` group, and turns the errors a user can
fix into one line, in one place (:class:`UgvmapGroup`).
"""

from __future__ import annotations

import click
from psycopg.errors import UndefinedTable
from sqlalchemy.exc import OperationalError, ProgrammingError

from app.errors import UgvmapError, UserError


class UgvmapGroup(click.Group):
    """The root group: every user-facing error, from any command, is one clear line and exit
    status 1 instead of a traceback, so no command has to catch them itself."""

    def invoke(self, ctx: click.Context) -> object:
        """Run the command; translate the user-facing errors it raises."""
        try:
            return super().invoke(ctx)
        except UserError as exc:
            raise click.ClickException(str(exc)) from exc
        except UgvmapError as exc:  # the same planner/services the HTTP API uses
            raise click.ClickException(f"{fault_name(exc)}: {exc.message}") from exc
        except OperationalError as exc:
            raise click.ClickException(
                f"cannot reach the database ({exc.orig}); `ugvmap db start`?") from exc
        except ProgrammingError as exc:
            if not isinstance(exc.orig, UndefinedTable):
                raise
            # A reachable database without the schema (a new cluster, another DATABASE_URL).
            raise click.ClickException(
                "the database has no ugvmap schema; run `ugvmap db upgrade`") from exc


def fault_name(exc: UgvmapError) -> str:
    """``NoRouteError`` -> ``NoRoute``: the fault's name as the HTTP API's ``code`` spells it
    (the HTTP layer's table is not imported: the command line stands on the core only)."""
    return type(exc).__name__.removesuffix("Error")


@click.group(cls=UgvmapGroup, context_settings={"help_option_names": ["-h", "--help"]})
def main() -> None:
    """ugvmap: imagery to map tiles, road network to routes, for unmanned ground vehicles."""


@main.group()
def ingest() -> None:
    """Batch jobs that write rasters and road networks into the store."""


def _register_capabilities() -> None:
    """Each capability owns its commands; this is the table of contents (one line each)."""
    from cli import backup, db, demo, ipm, jobs, layers, network, roads, routing, tokens, vehicle
    from cli.lanes import extract_lanes, ingest_lanes

    for command in (db.db, backup.backup, backup.restore, demo.demo, demo.serve,
                    jobs.jobs, jobs.worker, tokens.tokens, network.export, network.network,
                    layers.layers, routing.route,
                    roads.extract_roads, roads.evaluate_roads, roads.roads,
                    extract_lanes):
        main.add_command(command)
    for command in (network.ingest_network, layers.ingest_raster_cmd, roads.ingest_roads,
                    ipm.ingest_ipm_cmd, ingest_lanes):
        ingest.add_command(command)
    network.export.add_command(vehicle.export_package)


_register_capabilities()

if __name__ == "__main__":
    main()
