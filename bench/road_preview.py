"""A web map preview in seconds: the worker's extraction of a 1024 x 1024 px view of a layer
(``POST /layers/{slug}/previews``), timed against extracting the whole layer as ``ugvmap
ingest roads`` does, in the same run.

    .venv/bin/python bench/road_preview.py [--repeat 2]

The layer is the SpaceNet Las Vegas image of the shared data (1536 x 1792 px at z19),
ingested into a scratch database and raster store. Timed, each the fastest of ``--repeat``
rounds (the machine is shared): the preview of the 1024 x 1024 px view at the image's centre
(:func:`ingest.roads.layer.window_roads`: only that window is read) zero-shot, and again with
a person's sample (the 5 longest true roads in the view as road lines, adapted); the baseline
is the whole layer's zero-shot extraction (its mosaic and ``extract_roads``). Printed: the
seconds, their ratios to the baseline, and each against the issue's 10 s goal.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from pyproj import Transformer  # noqa: E402
from shapely.geometry import box, shape  # noqa: E402
from sqlalchemy import text  # noqa: E402

from testkit.scratch import bench_database  # noqa: E402

VEGAS = REPO.parent / "shared/data/road_imagery/spacenet_vegas"
VIEW_PX = 1024
GOAL_S = 10.0


def fastest(repeat: int, work: Callable[[], Any]) -> tuple[float, Any]:
    """The fastest of ``repeat`` runs of ``work`` (seconds) and its result."""
    best, result = float("inf"), None
    for _ in range(repeat):
        start = time.monotonic()
        result = work()
        best = min(best, time.monotonic() - start)
    return best, result


def main() -> None:
    """Ingest the layer, time the three extractions, print them."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    with bench_database("bench_preview"):
        from app.db.session import session_scope
        from ingest.raster.job import ingest_raster
        from ingest.roads.layer import _layer_sources, layer_mosaic, window_roads
        from ingest.roads.pipeline import ExtractParams, extract_roads
        from ingest.roads.sample import GeoSample

        ingest_raster([VEGAS / "RGB-PanSharpen_AOI_2_Vegas_img0.tif"], "vegas")
        with session_scope() as session:
            x0, y0, x1, y1, zoom = session.execute(text(
                "SELECT ST_XMin(bounds), ST_YMin(bounds), ST_XMax(bounds), ST_YMax(bounds), "
                "maxzoom FROM layers WHERE slug = 'vegas'")).one()
        half = VIEW_PX / 2 * 40075016.686 / 256 / 2 ** zoom
        to_map = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)
        to_lonlat = Transformer.from_crs("EPSG:3857", "EPSG:4326", always_xy=True)
        cx, cy = to_map.transform((x0 + x1) / 2, (y0 + y1) / 2)
        view = (*to_lonlat.transform(cx - half, cy - half),
                *to_lonlat.transform(cx + half, cy + half))
        truth = json.loads((VEGAS / "AOI_2_Vegas_img0.geojson").read_text())["features"]
        inside = [shape(f["geometry"]).intersection(box(*view)) for f in truth]
        lines = sorted((g for g in inside if g.geom_type == "LineString"),
                       key=lambda g: g.length, reverse=True)[:5]
        params = ExtractParams()

        def preview(sample):
            with session_scope() as session:
                return window_roads(session, "vegas", view, sample, params)

        def whole():
            with session_scope() as session:
                _, sources = _layer_sources(session, "vegas")
            return extract_roads(layer_mosaic([s.path for s in sources]), None, params)

        base_s, _ = fastest(args.repeat, whole)
        zero_s, (zero, _) = fastest(args.repeat, lambda: preview(None))
        taught_s, (taught, extraction) = fastest(
            args.repeat, lambda: preview(GeoSample(road_lines=lines)))
    classifier = f"{extraction.classifier}; {extraction.sample_note or 'no sample'}"
    print(f"baseline: whole layer (1536 x 1792 px) zero-shot extraction {base_s:.1f} s")
    for name, seconds, roads in (("preview, zero-shot", zero_s, len(zero)),
                                 (f"preview, 5 road lines ({classifier})", taught_s,
                                  len(taught))):
        print(f"{name}: {VIEW_PX} x {VIEW_PX} px view, {roads} roads, {seconds:.1f} s = "
              f"{seconds / base_s:.2f} x baseline; goal {GOAL_S:g} s: "
              f"{'met' if seconds <= GOAL_S else 'NOT met'}")


if __name__ == "__main__":
    main()
