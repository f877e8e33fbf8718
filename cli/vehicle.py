"""``ugvmap`` commands that prepare maps for the vehicle: the Lanelet2 export's report and
progress bar (``export network --format lanelet2``), and ``export package``.

Registered in :mod:`cli.main` on the ``export`` group of :mod:`cli.network`.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import click
from tqdm import tqdm

from app.lanelet2.build import summary_lines
from app.lanelet2.export import PROJECTOR_FILE, Lanelet2Export


@contextmanager
def progress_bar(description: str) -> Iterator[Callable[[str, float], None]]:
    """A % bar on a terminal (none otherwise) fed by ``progress(stage, fraction)``."""
    with tqdm(total=100, desc=description, unit="%",
              bar_format="{l_bar}{bar}| {n:.0f}% [{elapsed}<{remaining}{postfix}]",
              disable=not sys.stderr.isatty()) as bar:
        def progress(stage: str, fraction: float) -> None:
            bar.n = round(100 * fraction, 1)
            bar.set_postfix_str(stage)

        yield progress


def lanelet2_report(result: Lanelet2Export, folder: str | None = None) -> list[str]:
    """What a Lanelet2 export says on the terminal: counts, origin, how to load, defects.

    ``folder`` names where the map and its projector file are for the user, when that is not
    where they were written (a package is built in a hidden folder, then moved or zipped)."""
    where = folder or str(result.path.parent)
    s = result.summary
    lat, lon = result.origin
    lines = [f"wrote {result.path}: {s.lanelets} lanelets ({s.junction_lanelets} in junctions) "
             f"for {s.segments} segments of {result.network} (version {result.version}), "
             f"{s.traffic_lights} traffic-light elements",
             f"origin lat {lat} lon {lon} (UTM zone {result.utm_zone}); "
             f"{where}/{PROJECTOR_FILE} written for Autoware (LocalCartesianUTM)"]
    if s.from_paint:
        lines.append("from the paint: " + ", ".join(f"{n} {what}"
                                                    for what, n in s.from_paint.items()))
    if s.movements_dropped:
        lines.append(f"{len(s.movements_dropped)} junction movements not drawn (the roads "
                     "overlap where they meet): " + ", ".join(
                         f"node {n}: {a}->{b}" for n, a, b in s.movements_dropped[:10])
                     + (" ..." if len(s.movements_dropped) > 10 else ""))
    if s.defects:
        lines.append(f"{len(s.defects)} degenerate segments, handled by the documented rules:")
        lines += [f"  {line}" for line in summary_lines(s)]
    return lines


@click.command("package")
@click.option("--bbox", required=True, help="W,S,E,N in degrees: the mission area.")
@click.option("--layers", default="", help="Raster layers (slugs), comma-separated.")
@click.option("--network", "network", required=True, help="The road network to include.")
@click.option("--out", type=click.Path(path_type=Path), required=True,
              help="A new folder, or a .zip file.")
@click.option("--minzoom", type=int, help="Smallest raster zoom (default: each layer's).")
@click.option("--maxzoom", type=int, help="Largest raster zoom (default: each layer's).")
@click.option("--max-tiles", type=int, default=200_000, show_default=True,
              help="Refuse a package with more tiles than this.")
@click.option("--elevation-layer", metavar="SLUG",
              help="The elevation layer whose heights are the Lanelet2 map's ele (default 0).")
def export_package(bbox: str, layers: str, network: str, out: Path, minzoom: int | None,
                   maxzoom: int | None, max_tiles: int, elevation_layer: str | None) -> None:
    """Everything a vehicle needs offline for an area: raster layers as MBTiles, the network
    as GeoPackage, vector tiles and Lanelet2 (with map_projector_info.yaml), a manifest."""
    from sqlalchemy.orm import Session

    from app.lanelet2.export import parse_area
    from app.lanelet2.roads import snapshot
    from ingest.package.build import build_package, plan_package

    area = parse_area(bbox)
    assert area is not None  # --bbox is required
    slugs = [s.strip() for s in layers.split(",") if s.strip()]
    with snapshot() as conn:
        plan = plan_package(conn, area, slugs, network, minzoom=minzoom, maxzoom=maxzoom,
                            max_tiles=max_tiles, elevation_layer=elevation_layer)
        click.echo(f"packaging {plan.tile_count} tiles ("
                   + ", ".join([f"{p.slug} z{p.minzoom}-{p.maxzoom}: {len(p.tiles)}"
                                for p in plan.layers]
                               + [f"network: {len(plan.network_tiles)}"])
                   + f") and {plan.segments} segments of {network}")
        with progress_bar(f"package {out.name}") as progress:
            result = build_package(Session(bind=conn), plan, out, progress)
    files = result.manifest["files"]
    # The manifest lists (and checksums) every file but itself.
    click.echo(f"wrote {result.path}: manifest.json and {len(files)} files, "
               f"{sum(f['bytes'] for f in files) / 1e6:.1f} MB; "
               + "; ".join(f"{layer['slug']}: {layer['tiles']} tiles"
                           for layer in result.manifest["layers"]))
    for line in lanelet2_report(result.lanelet2, f"{out.name}/lanelet2")[1:]:
        click.echo(line)
