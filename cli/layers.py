"""``ugvmap ingest raster`` and ``ugvmap layers``: raster layers from the command line.

Registered in :mod:`cli.main`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from app.db.models import LAYER_KINDS
from app.errors import UserError
from app.tiles.store import resolve
from cli.jobs import absolute, enqueue_job, queue_option


@click.command("raster")
@click.argument("sources", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--layer", "slug", required=True, help="Layer slug (created if new).")
@click.option("--title", help="Human title of the layer.")
@click.option("--kind", default="orthophoto", show_default=True,
              type=click.Choice(list(LAYER_KINDS)),
              help="elevation: a DEM (DSM or DTM) of heights in metres, see docs/terrain.md")
@click.option("--crs", help="CRS of world-file images (e.g. EPSG:32633).")
@click.option("--priority", default=0, show_default=True, type=int,
              help="Higher priority sources are drawn over lower ones; ties: newest on top.")
@click.option("--gcps", "gcps_file", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="CSV pixel_x,pixel_y,X,Y[,id] (lon/lat, or in --crs) to georeference SRC.")
@click.option("--gcp-method", default="poly1", show_default=True,
              type=click.Choice(["poly1", "poly2", "tps"]))
@click.option("--replace", is_flag=True,
              help="Re-ingest files already in the layer: the sources with the same content "
                   "or file name are replaced (without it such a file is refused).")
@click.option("--add", is_flag=True,
              help="Add files that do not touch the layer's area as separate areas (without "
                   "it such a file is refused).")
@queue_option
def ingest_raster_cmd(sources: tuple[Path, ...], slug: str, title: str | None, kind: str,
                      crs: str | None, priority: int, gcps_file: Path | None,
                      gcp_method: str, replace: bool, add: bool, queued: bool) -> None:
    """Ingest GeoTIFFs / world-file images / zone mosaics / GCP images into layer SLUG.

    A file whose content is already a source of the layer is refused unless --replace; a
    file that neither overlaps nor touches the layer's sources (for a new layer: the first
    file given) unless --add. Each source's line says where it landed (centre lon,lat and
    size): check it, a wrong --crs is a valid place elsewhere.
    With --queue, workers write one source each, in parallel, and the layer is registered
    once when all are written."""
    from app.jobs.recorder import JobRecorder
    from ingest.raster.footprint import where
    from ingest.raster.gcps import ingest_with_gcps
    from ingest.raster.job import ingest_raster

    if gcps_file is not None and len(sources) != 1:
        raise UserError("--gcps georeferences exactly one SRC image")
    if queued:
        enqueue_job("ingest-raster", {
            "sources": [absolute(s) for s in sources], "layer": slug, "title": title,
            "kind": kind, "crs": crs, "priority": priority, "gcps": absolute(gcps_file),
            "gcp_method": gcp_method, "replace": replace, "add": add})
        return
    params = {"sources": [str(s) for s in sources], "kind": kind, "crs": crs,
              "gcps": str(gcps_file) if gcps_file else None}
    with JobRecorder("ingest-raster", slug, params) as job:
        options: dict[str, Any] = {"title": title, "kind": kind, "priority": priority,
                                   "on_progress": job.progress, "replace": replace,
                                   "add": add}
        if gcps_file is None:
            report = ingest_raster(list(sources), slug, crs=crs, **options)
        else:
            accuracy, report = ingest_with_gcps(sources[0], slug, gcps_file, gcp_method,
                                                crs, **options)
            click.echo(accuracy.table())
    for src in report.sources:
        click.echo(f"{src.name}: {src.width}x{src.height} px at z{src.zoom} "
                   f"({src.resolution_m:.3f} m/px), {where(src.meta['bounds_4326'])} -> "
                   f"{resolve(src.uri)}")
        for warning in src.meta.get("warnings", []):
            click.echo(f"Warning: {warning}", err=True)
    click.echo(report.summary())


@click.group()
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
        raise UserError(f"no raster layer {slug!r}")
    for key in ("slug", "title", "kind", "minzoom", "maxzoom", "resolution_m", "bounds",
                "version"):
        click.echo(f"{key}: {layer[key]}")
    for src in layer["sources"]:
        click.echo(f"  source {src['id']}: {src['name']} z{src['zoom']} {src['width']}x"
                   f"{src['height']} priority={src['priority']} georef={src['georef']} "
                   f"ingested {src['ingested_at']:%Y-%m-%d %H:%M:%S} {resolve(src['uri'])}")


@layers.command("delete")
@click.argument("slug")
@click.option("--yes", is_flag=True, help="Do not ask for confirmation.")
def layers_delete(slug: str, yes: bool) -> None:
    """Delete a layer, its catalogue rows and its COGs (files or objects) in the raster
    store; asks first unless --yes, like `ugvmap network delete`."""
    from app.db.session import get_engine
    from app.tiles.catalog import delete_layer, get_layer
    from app.tiles.store import remove_files

    with get_engine().connect() as conn:
        layer = get_layer(conn, slug)
    if layer is None:
        raise UserError(f"no raster layer {slug!r}")
    if not yes:
        click.confirm(f"Delete raster layer {slug!r} with its {len(layer['sources'])} sources "
                      "and their files?", abort=True)
    with get_engine().begin() as conn:
        uris = delete_layer(conn, slug)
    if uris is None:
        raise UserError(f"no raster layer {slug!r}")
    remove_files(get_engine(), uris)
    click.echo(f"deleted layer {slug} ({len(uris)} files)")


@layers.command("remove-source")
@click.argument("slug")
@click.argument("source")
@click.option("--yes", is_flag=True, help="Do not ask for confirmation.")
def layers_remove_source(slug: str, source: str, yes: bool) -> None:
    """Remove one SOURCE (its id or file name, as `ugvmap layers show SLUG` lists them) from
    layer SLUG, with its COG; the other sources stay. Asks first unless --yes."""
    from ingest.raster.removal import remove_source

    if not yes:
        click.confirm(f"Remove source {source!r} and its file from raster layer {slug!r}?",
                      abort=True)
    click.echo(remove_source(slug, source).summary())


@layers.command("export")
@click.argument("slug")
@click.option("--out", required=True, type=click.Path(dir_okay=False, path_type=Path),
              help="The Cloud-Optimized GeoTIFF to write (EPSG:3857, the layer's finest zoom).")
def layers_export(slug: str, out: Path) -> None:
    """Write layer SLUG as one COG: its sources mosaicked in paint order by GDAL."""
    from ingest.raster.export import export_layer

    if out.suffix.lower() not in (".tif", ".tiff"):
        raise UserError(f"--out {out}: a COG is a .tif file")
    if not out.parent.is_dir():
        raise UserError(f"--out {out}: no such directory {out.parent}")
    zoom = export_layer(slug, out)
    click.echo(f"layer {slug} -> {out} (z{zoom}, {out.stat().st_size / 1e6:.1f} MB)")


@layers.command("labels")
@click.argument("slug")
@click.option("--add", "add_file", type=click.Path(exists=True, dir_okay=False, path_type=Path),
              help="Add the features of this GeoJSON file (lon/lat) as labels, all or none.")
@click.option("--label", type=click.Choice(["road", "not_road"]),
              help="With --add: the label of features without a 'label' property.")
@click.option("--delete", "delete_id", type=click.IntRange(1), metavar="ID",
              help="Delete the label ID.")
@click.option("--clear", is_flag=True, help="Delete all the layer's labels.")
def layers_labels(slug: str, add_file: Path | None, label: str | None, delete_id: int | None,
                  clear: bool) -> None:
    """List the labels of layer SLUG (road / not-road lines and areas road extraction learns
    from), or add, delete or clear them."""
    import getpass
    import json

    from app.db.session import session_scope
    from app.labels import store

    if sum(x is not None and x is not False for x in (add_file, delete_id, clear)) > 1:
        raise UserError("give one of --add, --delete and --clear")
    if label is not None and add_file is None:
        raise UserError("--label goes with --add")
    with session_scope() as session:
        if add_file is not None:
            try:
                body = json.loads(add_file.read_text())
            except (OSError, UnicodeDecodeError, ValueError) as exc:
                raise UserError(f"{add_file}: not a GeoJSON file ({exc})") from exc
            added = store.add_labels(session, slug, store.parse_labels(body, label),
                                     f"cli:{getpass.getuser()}")
            click.echo(f"added {len(added)} labels to layer {slug} "
                       f"(ids {added[0]['id']}..{added[-1]['id']})")
        elif delete_id is not None:
            store.delete_label(session, slug, delete_id)
            click.echo(f"deleted label {delete_id} of layer {slug}")
        elif clear:
            click.echo(f"deleted {store.clear_labels(session, slug)} labels of layer {slug}")
        else:
            for feature in store.list_labels(session.connection(), slug):
                props = feature["properties"]
                click.echo(f"{feature['id']}\t{props['label']}\t{feature['geometry']['type']}"
                           f"\t{props['created_by']}\t{props['created_at'][:19]}")
