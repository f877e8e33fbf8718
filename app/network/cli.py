"""``ugvmap`` commands for road networks: import, export, validate, API tokens.

Registered on the groups of ``app.cli``; ``CliError`` is imported when needed because
``app.cli`` imports this module.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click
from tqdm import tqdm


def _user_errors(func: Callable[..., Any]) -> Callable[..., Any]:
    """Turn the domain's ValueErrors into one-line CLI errors (exit 1, no traceback)."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        from sqlalchemy.exc import OperationalError

        from app.cli import CliError

        try:
            return func(*args, **kwargs)
        except ValueError as exc:
            raise CliError(str(exc)) from exc
        except OperationalError as exc:
            raise CliError(f"cannot reach the database ({exc.orig}); `ugvmap db start`?") from exc

    return wrapper


@click.command("network")
@click.argument("file", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--network", "network", required=True, help="Network name (slug).")
@click.option("--replace", is_flag=True, help="Replace the network's segments if it exists.")
@_user_errors
def ingest_network(file: Path, network: str, replace: bool) -> None:
    """Import a GeoJSON / GeoPackage / OSM (.osm, .osm.pbf) road file as network NAME."""
    from app.db.session import session_scope
    from ingest.network import import_network

    with tqdm(total=1, desc=f"import {file.name}", disable=not sys.stderr.isatty()) as bar, \
            session_scope() as session:
        summary = import_network(session, file, network, replace=replace)
        bar.update(1)
    click.echo(f"network {summary.network}: {summary.segments} segments, {summary.nodes} nodes, "
               f"{summary.total_length_m / 1000:.3f} km from {summary.lines_read} lines "
               f"({summary.crossings_noded} crossings noded, "
               f"{summary.duplicates_dropped} duplicates dropped)")
