"""Demo loader: the shared sample orthophotos as ready-to-browse raster layers.

Called by the demo set-up; re-running it is harmless (layers that exist are left alone).
The Landsat scene (300 m/px) gets its own layer instead of sharing one with the drone
orthophotos (0.3-0.5 m/px), which cover a few hectares on two other continents: one layer of
two separate areas (``add``), showing what such a layer is.
"""

from __future__ import annotations

from pathlib import Path

from app.db.session import get_engine
from app.tiles.catalog import layer_row
from ingest.raster.job import IngestReport, ingest_raster

SAMPLE_LAYERS = {
    "drone-orthophotos": ("Drone orthophotos (Pix4D, WebODM samples)",
                          ["pix4d_alpha_nodata.tif", "webodm_orthophoto.tif"]),
    "landsat-rgb": ("Landsat RGB sample (rasterio RGB.byte.tif)", ["RGB.byte.tif"]),
}


def ingest_sample_orthophotos(orthophotos_dir: Path) -> list[IngestReport]:
    """Ingest the samples under ``orthophotos_dir`` (``shared/data/orthophotos``)."""
    with get_engine().connect() as conn:
        missing = {slug: spec for slug, spec in SAMPLE_LAYERS.items()
                   if layer_row(conn, slug) is None}
    reports = []
    for slug, (title, names) in missing.items():
        paths = [orthophotos_dir / n for n in names if (orthophotos_dir / n).is_file()]
        if paths:
            reports.append(ingest_raster(paths, slug, title=title, kind="orthophoto",
                                         add=True))
    return reports
