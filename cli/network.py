"""``ugvmap`` commands for road networks: import, export, validate, settings, delete.

Registered in :mod:`cli.main`. Bad input (unreadable file, unknown network, bad name) is a
:class:`~app.errors.UserError` from the code below, shown as one line by the CLI root.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import click
from sqlalchemy import text
from tqdm import tqdm

from app.errors import UserError
from app.network.settings import DEFAULT_SPEEDS_KPH, AttributeRules
from app.routing.profiles import usage_report
from cli.jobs import absolute, enqueue_job, queue_option
from cli.resurvey import change_set_line, check_update, update_options
from cli.rules import given_rules, rule_options


@click.command("network")
@click.argument("file", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--network", "network", required=True, help="Network name (slug).")
@click.option("--replace", is_flag=True, help="Replace the network's segments if it exists.")
@update_options
@queue_option
def ingest_network(file: Path, network: str, replace: bool, update: bool,
                   tolerances: dict[str, float], queued: bool) -> None:
    """Import a GeoJSON / GeoPackage / OSM (.osm, .osm.pbf) road FILE as a network, or with
    --update match it against the network and propose the changes as a change set."""
    check_update(replace, update, tolerances)
    if queued:
        enqueue_job("ingest-network",
                    {"file": absolute(file), "network": network, "replace": replace,
                     "update": update, "tolerances": tolerances})
        return
    if update:
        _update_from_file(file, network, tolerances)
        return
    from app.db.session import session_scope
    from app.jobs.recorder import JobRecorder, Throttle
    from ingest.network import import_network

    with JobRecorder("ingest-network", network, {"file": str(file), "replace": replace}) as job, \
            tqdm(total=100, desc=f"import {file.name}", unit="%",
                 bar_format="{l_bar}{bar}| {n:.0f}% [{elapsed}<{remaining}{postfix}]",
                 disable=not sys.stderr.isatty()) as bar, session_scope() as session:
        throttle = Throttle(job.progress)

        def progress(message: str, fraction: float) -> None:
            bar.n = round(100 * fraction, 1)
            bar.set_postfix_str(message)
            throttle(fraction, message)

        summary = import_network(session, file, network, replace=replace, progress=progress)
        classes: dict[str, int] = dict(session.execute(text(
            "SELECT road_class, count(*) FROM road_segments WHERE network_id = :id "
            "GROUP BY road_class"), {"id": summary.network_id}).all())
    click.echo(f"network {summary.network}: {summary.segments} segments, {summary.nodes} nodes, "
               f"{summary.total_length_m / 1000:.3f} km from {summary.lines_read} lines "
               f"({summary.crossings_noded} crossings noded, "
               f"{summary.duplicates_dropped} duplicates dropped)")
    click.echo(usage_report(classes))  # every way is kept; which vehicle may drive which


def _update_from_file(file: Path, network: str, tolerances: dict[str, float]) -> None:
    from app.db.session import session_scope
    from app.network.resurvey.matching import Tolerances
    from ingest.network.update import update_from_file

    with session_scope() as session:
        proposed = update_from_file(session, file, network, tol=Tolerances(**tolerances))
    click.echo(change_set_line(proposed))


@click.group("export")
def export() -> None:
    """Write stored data to files."""


@export.command("network")
@click.argument("name")
@click.option("--format", "fmt", type=click.Choice(["geojson", "gpkg", "osm", "lanelet2"]),
              required=True)
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Output file (for osm: .osm or .osm.pbf; for geojson: x.geojson writes "
                   "x.segments.geojson and x.nodes.geojson; for lanelet2: an .osm file, with "
                   "map_projector_info.yaml written beside it).")
@click.option("--bbox", help="W,S,E,N in degrees: only the segments meeting it (whole).")
@click.option("--origin", help="lanelet2: LAT,LON of the map origin (default: the centre of "
                               "the exported roads, rounded to 1e-4°).")
@click.option("--elevation-layer", metavar="SLUG",
              help="lanelet2: the elevation layer whose heights are the nodes' ele "
                   "(default: ele 0).")
def export_network(name: str, fmt: str, out: Path, bbox: str | None,
                   origin: str | None, elevation_layer: str | None) -> None:
    """Export network NAME losslessly (import of the file gives the same network; for
    GeoJSON, import the .segments file: its .nodes file is read with it), or as a lane-level
    Lanelet2 map (every lanelet tagged segment_id) for Autoware-style stacks."""
    from app.lanelet2.export import parse_area, parse_origin

    area = parse_area(bbox)
    if fmt == "lanelet2":
        _export_lanelet2(name, out, area, parse_origin(origin), elevation_layer)
        return
    if origin is not None or elevation_layer is not None:
        raise UserError("--origin and --elevation-layer apply to --format lanelet2 only")
    from app.db.session import session_scope
    from ingest.network.exporter import export_network as export_file

    with session_scope() as session:
        summary = export_file(session, name, out, fmt, area)
    click.echo(f"wrote {summary.segments} segments and {summary.nodes} nodes of {name} to "
               + " and ".join(str(f) for f in summary.files))


def _export_lanelet2(name: str, out: Path, area: tuple[float, float, float, float] | None,
                     origin: tuple[float, float] | None, elevation_layer: str | None) -> None:
    from app.lanelet2.export import export_lanelet2
    from app.lanelet2.roads import snapshot
    from cli.vehicle import lanelet2_report, progress_bar

    with progress_bar(f"lanelet2 {name}") as progress, snapshot() as conn:
        result = export_lanelet2(conn, name, out, bbox=area, origin=origin, progress=progress,
                                 elevation_layer=elevation_layer)
    for line in lanelet2_report(result):
        click.echo(line)


@click.group("network")
def network() -> None:
    """Road network maintenance."""


@network.command("list")
def network_list() -> None:
    """One line per network: name, segments, nodes, version, last change, title (as
    `ugvmap layers list` lists layers; `GET /networks` answers the same rows)."""
    from sqlalchemy import text

    from app.db.session import get_engine
    from app.network.summary import NETWORKS_SQL

    with get_engine().connect() as conn:
        rows = conn.execute(text(NETWORKS_SQL), {"name": None}).all()
    for r in rows:
        click.echo(f"{r.name}\t{r.segments} segments\t{r.nodes} nodes\tv{r.version}"
                   f"\t{r.updated_at:%Y-%m-%d %H:%M}\t{r.title or ''}")


@network.command("changes")
@click.argument("name")
@click.argument("change_set", type=int, required=False)
@click.option("--json", "as_json", is_flag=True, help="Print JSON (a change set: GeoJSON).")
def changes(name: str, change_set: int | None, as_json: bool) -> None:
    """List NAME's change sets (what each re-survey proposed and what was decided), or show
    one CHANGE_SET's proposals. Review them in the web map or over the HTTP API."""
    from app.db.session import session_scope
    from app.network.resurvey import changes as sets

    with session_scope() as session:
        if change_set is None:
            rows = sets.change_sets(session, name)
        else:
            rows = [sets.change_set(session, name, change_set)]
    if as_json:
        click.echo(json.dumps(rows if change_set is None else rows[0], indent=1))
        return
    if not rows:
        click.echo(f"network {name} has no change sets")
    for row in rows:
        decided = ", ".join(f"{n} {k}" for k, n in sorted(row["proposals"].items()))
        click.echo(f"{row['id']}\t{row['created_at'][:16]}\t{row['status']}\t{row['source']}"
                   f"\t{row['created_by']}\t{decided or 'nothing proposed'}")
    if change_set is not None:
        for feature in rows[0]["features"]:
            p = feature["properties"]
            what = f"segment {p['segment_id']}" if p["segment_id"] else "new road"
            click.echo(f"  change {feature['id']}: {p['kind']} {what} ({p['status']})"
                       + (" edited by a person" if p["edited"] else ""))


@network.command("validate")
@click.argument("name")
@click.option("--json", "as_json", is_flag=True,
              help="Print everything as JSON (every piece and dead end).")
def validate(name: str, as_json: bool) -> None:
    """Check NAME's topology invariants, list its connected pieces (size, bounding box) and
    dead ends (lon/lat); exit 1 if an invariant is broken."""
    from app.db.session import session_scope
    from cli.ops.network_integrity import check_network

    with session_scope() as session:
        report = check_network(session, name)
    if as_json:
        click.echo(json.dumps(report.as_json(), indent=1))
        if not report.ok:
            raise SystemExit(1)
        return
    lines = report.lines()
    for line in lines[:-1]:
        click.echo(line)
    if not report.ok:
        raise UserError(lines[-1])
    click.echo(lines[-1])


@network.command("settings")
@click.argument("name")
@rule_options
@click.option("--reset", is_flag=True, help="Forget the network's overrides first.")
@click.option("--json", "as_json", is_flag=True, help="Print the rules as JSON.")
def settings(name: str, reset: bool, as_json: bool, **options: Any) -> None:
    """Show (and with options, change) the attribute rules road extraction applies to NAME.

    Options given are stored as the network's overrides (a new network is created empty);
    `ugvmap ingest roads` applies them unless its own rule options override them again.
    """
    from app.db.session import session_scope
    from ingest.roads.rules import effective_rules, network_rules, save_network_rules

    changes = given_rules(options)
    with session_scope() as session:
        if reset or changes.overrides():
            stored = save_network_rules(session, name, changes, reset=reset)
        else:
            if session.execute(text("SELECT 1 FROM networks WHERE name = :n"),
                               {"n": name}).first() is None:
                raise UserError(f"network {name[:100]!r} does not exist (give a rule option to "
                                "create it with these rules)")
            stored = network_rules(session, name)
        rules = effective_rules(session, name)
    if as_json:
        click.echo(json.dumps({"network": name, "overrides": stored.overrides(),
                               "rules": rules.model_dump(mode="json"),
                               "default_speeds_kph": DEFAULT_SPEEDS_KPH}, indent=1))
        return
    for line in rules_lines(rules, stored):
        click.echo(line)


def rules_lines(rules: AttributeRules, stored: AttributeRules) -> list[str]:
    """The rules as printed by ``network settings``, each marked with where it comes from."""
    mark = {True: "network", False: "default"}
    given = stored.model_fields_set
    out = [f"lane width: {rules.lane_width_m:g} m ({mark['lane_width_m' in given]})",
           f"junction segments: at most {rules.junction_length_m:g} m between two junctions "
           f"({mark['junction_length_m' in given]})",
           f"classes ({mark['classes' in given]}), first match wins:"]
    out += [f"  {row.road_class}: width >= {row.min_width_m:g} m, through >= "
            f"{row.min_through:g}" for row in rules.classes]
    out.append("  otherwise: unclassified")
    out.append("speeds (km/h):")
    for cls in dict.fromkeys([*DEFAULT_SPEEDS_KPH, *rules.speed_kph]):
        speed = rules.speed(cls)
        out.append(f"  {cls}: {'no limit' if speed is None else f'{speed:g}'} "
                   f"({mark[cls in stored.speed_kph]})")
    return out


@network.command("delete")
@click.argument("name")
@click.option("--yes", is_flag=True, help="Do not ask for confirmation.")
def delete(name: str, yes: bool) -> None:
    """Delete network NAME with its segments, nodes and edit history (asks first)."""
    from app.db.session import session_scope
    from cli.ops.network_deletion import delete_network

    if not yes:
        click.confirm(f"Delete network {name!r} with all its segments, nodes and edit history?",
                      abort=True)
    with session_scope() as session:
        gone = delete_network(session, name)
    click.echo(f"deleted network {gone.name}: {gone.segments} segments, {gone.nodes} nodes, "
               f"{gone.edits} history entries")
