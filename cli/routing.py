"""``ugvmap route NAME --points ...``: the route service from the command line.

Answers exactly like ``GET /networks/{name}/route`` (same planner), printing the OSRM-shaped
JSON, the dense waypoints, or a one-line-per-leg summary.
"""

from __future__ import annotations

import click
import orjson

from app.errors import DatabaseUnavailableError
from app.routing.costs import Cost
from app.routing.options import FORMATS, GEOMETRIES, parse, parse_points
from app.routing.profiles import ALIASES, DEFAULT, PROFILES
from app.routing.reads import read_connection


@click.command("route")
@click.argument("network")
@click.option("--points", required=True, metavar="LON,LAT;LON,LAT[;...]",
              help="the points, visited in order")
@click.option("--profile", type=click.Choice([*PROFILES, *ALIASES]), default=DEFAULT.name,
              show_default=True,
              help="the vehicle: car (or driving) never drives footways, cycleways, paths, "
                   "steps...; sidewalk (or robot) may")
@click.option("--cost", type=click.Choice([c.value for c in Cost]), default="time",
              show_default=True)
@click.option("--avoid", default="", metavar="CLASSES",
              help="road classes to avoid, comma-separated")
@click.option("--optimize", is_flag=True, help="best order of the intermediate points")
@click.option("--geometries", type=click.Choice(GEOMETRIES), default="geojson",
              show_default=True)
@click.option("--format", "fmt", type=click.Choice([*FORMATS, "summary"]), default="summary",
              show_default=True, help="summary: one line per leg")
@click.option("--spacing", default=None, metavar="METRES",
              help="metres between points for --format waypoints (default 1)")
@click.option("--radius", default=None, metavar="METRES|unlimited",
              help="snap radius in metres (default 50)")
@click.option("--offroad", is_flag=True,
              help="points farther than the snap radius from every road get off-road legs "
                   "over --elevation (docs/terrain.md)")
@click.option("--elevation", default=None, metavar="SLUG",
              help="with --offroad: the elevation layer (DTM) driven on")
@click.option("--surface", default=None, metavar="SLUG",
              help="with --offroad: the DSM layer whose height above the DTM is a step")
@click.option("--forbid", default=None, metavar="SLUG[,SLUG...]",
              help="with --offroad: raster layers whose pixels above 0 are never driven")
@click.option("--max-slope", default=None, metavar="DEGREES",
              help="with --offroad: the steepest slope driven (default: the profile's)")
@click.option("--max-step", default=None, metavar="METRES",
              help="with --offroad: the highest step crossed (default: the profile's)")
def route(network: str, points: str, profile: str, cost: str, avoid: str, optimize: bool,
          geometries: str, fmt: str, spacing: str | None, radius: str | None, offroad: bool,
          elevation: str | None, surface: str | None, forbid: str | None,
          max_slope: str | None, max_step: str | None) -> None:
    """Plan a route on NETWORK through the given points."""
    # Here, not at the top: the planner loads routing's compiled kernels (numba), which every
    # other command (`ugvmap --help`, `db start`...) would pay for at start-up.
    from app.routing.planner import plan_route

    raw = {"profile": profile, "cost": cost, "avoid": avoid,
           "optimize": "true" if optimize else "false"}
    if fmt == "waypoints":
        raw.update(format="waypoints", **({"spacing": spacing} if spacing is not None else {}))
    else:
        raw.update(geometries=geometries)
    if radius is not None:
        raw["radius"] = radius
    given = {"elevation": elevation, "surface": surface, "forbid": forbid,
             "max_slope": max_slope, "max_step": max_step}
    raw.update({k: v for k, v in given.items() if v is not None})
    if offroad:
        raw["offroad"] = "true"
    pts = parse_points(points)  # option errors (UgvmapError): one line from cli.main
    opts = parse(raw, "ugvmap", len(pts))
    try:
        with read_connection() as conn:
            body = plan_route(conn, network, pts, opts)
    except DatabaseUnavailableError as exc:  # said like every other command says it
        raise click.ClickException(f"cannot reach the database ({exc.message}); "
                                   "`ugvmap db start`?") from exc
    if fmt != "summary":
        click.echo(orjson.dumps(body, option=orjson.OPT_SERIALIZE_NUMPY).decode())
        return
    r = body["routes"][0]
    for k, leg in enumerate(r["legs"]):
        if "segments" in leg:
            click.echo(f"leg {k}: {leg['distance']:.1f} m, {leg['duration']:.1f} s, "
                       f"{len(leg['segments'])} segments")
            continue
        click.echo(f"leg {k}: {leg['distance']:.1f} m, {leg['duration']:.1f} s, " + ", ".join(
            f"{s['mode']} {s['distance']:.0f} m" for s in leg["steps"]))
    ranks = [w["waypoint_index"] for w in body["waypoints"]]
    order = sorted(range(len(ranks)), key=ranks.__getitem__)
    click.echo(f"total: {r['distance']:.1f} m, {r['duration']:.1f} s"
               + (f", points visited in order {order}" if optimize else ""))
