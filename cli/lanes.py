"""``ugvmap extract-lanes``: painted lane markings of one image into GeoJSON (no database), and
``ugvmap ingest lanes``: a layer's markings stored as the lanes of a network's segments.

Heavy imports (OpenCV, scikit-image) happen inside the command so ``ugvmap --help`` stays
instant; user mistakes (imagery too coarse, no georeference and no --resolution) are
:class:`~app.errors.UserError`, shown as one line by the CLI root.
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path

import click

from app.errors import UserError
from cli.jobs import enqueue_job, queue_option


@click.command("extract-lanes")
@click.argument("image", type=click.Path(path_type=Path, dir_okay=False))
@click.option("--resolution", type=float,
              help="Metres per pixel (required without georeference; at most 0.2).")
@click.option("--out", "out_path", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="Output GeoJSON (LineStrings with kind, colour, width_m, confidence).")
@click.option("--road-model/--no-road-model", default=True, show_default=True,
              help="Keep only paint on or beside road as the road model sees it (aerial "
                   "imagery of 0.1-0.2 m/px spanning 48 m or more, where it sees road: roofs "
                   "and car parks are not road).")
def extract_lanes(image: Path, resolution: float | None, out_path: Path,
                  road_model: bool) -> None:
    """Extract the painted lane markings of IMAGE into GeoJSON.

    Each marking is a line with a kind (solid, dashed, stop_line, road_edge, other), a colour
    (white, yellow, unknown), its width and a confidence; a dashed line is one line across its
    gaps. Coordinates are the image's CRS, or source pixels when it has no georeference.
    """
    from ingest.lanes import check_resolution
    from ingest.lanes.extract import extract_markings, markings_geojson
    from ingest.roads.georef import read_image

    if resolution is not None:
        check_resolution(resolution)
    try:
        img = read_image(image, resolution)
    except MemoryError as exc:
        raise UserError(f"{image}: too big to read into memory") from exc
    road = None
    if road_model:
        from ingest.lanes.road import model_road

        road = model_road(img)
    markings = extract_markings(img, road=road)
    try:
        out_path.write_text(json.dumps(markings_geojson(markings, img)))
    except OSError as exc:
        raise UserError(f"cannot write {out_path}: {exc.strerror}") from exc
    kinds = Counter(m.kind for m in markings)
    summary = ", ".join(f"{n} {kind}" for kind, n in kinds.most_common()) or "no marking found"
    where = ("" if not road_model else " on the road model's roads" if road is not None
             else " (the road model not used: finer than 0.1 m/px, under 48 m across, or no road "
             "seen)")
    click.echo(f"{len(markings)} markings ({summary}){where} -> {out_path}")


@click.command("lanes")
@click.option("--layer", "slug", required=True, help="Raster layer to read the paint from.")
@click.option("--network", required=True, help="Network whose segments get the lanes.")
@queue_option
def ingest_lanes(slug: str, network: str, queued: bool) -> None:
    """Read the lane markings of raster layer SLUG where NETWORK's roads are and store each
    segment's lanes (count per direction and widths, in ranges along it) and lane boundaries.

    Imagery coarser than 0.2 m/px is refused before anything is read. The rows of every
    segment with paint are replaced in one transaction; segments without paint keep theirs.
    A segment's lanes_forward/lanes_backward follow its paint unless a person edited it.
    """
    if queued:
        enqueue_job("ingest-lanes", {"layer": slug, "network": network})
        return
    from app.db.session import session_scope
    from app.jobs.recorder import JobRecorder, Throttle
    from ingest.lanes.layer import ingest_layer_lanes

    with JobRecorder("ingest-lanes", network, {"layer": slug}) as job, \
            session_scope() as session:
        throttle = Throttle(job.progress)

        def progress(fraction: float, message: str) -> None:
            throttle(fraction, message)
            if sys.stderr.isatty():
                click.echo(f"  {message}", err=True)

        done = ingest_layer_lanes(session, slug, network, progress)
    for line in done.lines():
        click.echo(line)

