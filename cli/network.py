"""``ugvmap`` commands for road networks: import, export, validate, delete.

Registered in :mod:`cli.main`. Bad input (unreadable file, unknown network, bad name) is a
:class:`~app.errors.UserError` from the code below, shown as one line by the CLI root.
"""

from __future__ import annotations

import sys
from pathlib import Path

import click
from tqdm import tqdm

from app.errors import UserError
from cli.jobs import absolute, enqueue_job, queue_option


@click.command("network")
@click.argument("file", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--network", "network", required=True, help="Network name (slug).")
@click.option("--replace", is_flag=True, help="Replace the network's segments if it exists.")
@queue_option
def ingest_network(file: Path, network: str, replace: bool, queued: bool) -> None:
    """Import a GeoJSON / GeoPackage / OSM (.osm, .osm.pbf) road FILE as a network."""
    if queued:
        enqueue_job("ingest-network",
                    {"file": absolute(file), "network": network, "replace": replace})
        return
    from app.db.session import session_scope
    from app.jobs.recorder import JobRecorder, Throttle
    from ingest.network import import_network

    with JobRecorder("ingest-network", network, {"file": str(file), "replace": replace}) as job, \
            tqdm(total=100, desc=f"import {file.name}", unit="%",
                 bar_format="{l_bar}{bar}| {n:.0f}% [{elapsed}<{remaining}{postfix}]",
                 disable=not sys.stderr.isatty()) as bar, session_scope() as session:
        throttle = Throttle(job)

        def progress(message: str, fraction: float) -> None:
            bar.n = round(100 * fraction, 1)
            bar.set_postfix_str(message)
            throttle(fraction, message)

        summary = import_network(session, file, network, replace=replace, progress=progress)
    click.echo(f"network {summary.network}: {summary.segments} segments, {summary.nodes} nodes, "
               f"{summary.total_length_m / 1000:.3f} km from {summary.lines_read} lines "
               f"({summary.crossings_noded} crossings noded, "
               f"{summary.duplicates_dropped} duplicates dropped)")


@click.group("export")
def export() -> None:
    """Write stored data to files."""


@export.command("network")
@click.argument("name")
@click.option("--format", "fmt", type=click.Choice(["geojson", "gpkg", "osm"]), required=True)
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Output file (for osm: .osm or .osm.pbf; for geojson: x.geojson writes "
                   "x.segments.geojson and x.nodes.geojson).")
def export_network(name: str, fmt: str, out: Path) -> None:
    """Export network NAME losslessly (import of the file gives the same network; for
    GeoJSON, import the .segments file: its .nodes file is read with it)."""
    from app.db.session import session_scope
    from ingest.network.exporter import export_network as export_file

    with session_scope() as session:
        summary = export_file(session, name, out, fmt)
    click.echo(f"wrote {summary.segments} segments and {summary.nodes} nodes of {name} to "
               + " and ".join(str(f) for f in summary.files))


@click.group("network")
def network() -> None:
    """Road network maintenance."""


@network.command("validate")
@click.argument("name")
def validate(name: str) -> None:
    """Check NAME's topology invariants; exit 1 if any is broken."""
    from app.db.session import session_scope
    from app.network.integrity import check_network

    with session_scope() as session:
        report = check_network(session, name)
    for line in report.lines()[:-1]:
        click.echo(line)
    if not report.ok:
        raise UserError(report.lines()[-1])
    click.echo(report.lines()[-1])


@network.command("delete")
@click.argument("name")
@click.option("--yes", is_flag=True, help="Do not ask for confirmation.")
def delete(name: str, yes: bool) -> None:
    """Delete network NAME with its segments, nodes and edit history (asks first)."""
    from app.db.session import session_scope
    from app.network.deletion import delete_network

    if not yes:
        click.confirm(f"Delete network {name!r} with all its segments, nodes and edit history?",
                      abort=True)
    with session_scope() as session:
        gone = delete_network(session, name)
    click.echo(f"deleted network {gone.name}: {gone.segments} segments, {gone.nodes} nodes, "
               f"{gone.edits} history entries")
