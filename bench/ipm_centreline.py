"""The road centreline from IPM drives made with *other* conventions than our own renderer's:
``ugvmap ingest ipm`` then ``ugvmap ingest roads`` with defaults only, scored against the true
centre line.

    .venv/bin/python bench/ipm_centreline.py [--only NAME ...] [--frames N]

The drives are :data:`testkit.ipm_world.VARIED` (a renderer that shares nothing with
``ingest.ipm.synthetic`` or the pipeline but the documented contract): a grey road on darker
grey ground with the vehicle on the centre line (the issue's drive), a wide road with a lane
change across the centre line under a higher camera, a narrow concrete lane with the vehicle
right of centre under a low camera and a coarser panorama, dark asphalt on a brighter grey
gravel verge with the vehicle left of centre. Both commands run as a user runs them (a fresh
``ugvmap`` process, this checkout, a scratch database and raster store). Printed per drive:
the median and largest distance of the stored centreline (every 0.1 m) from the true one, its
signed median (+ outside the bend), the width found vs the true width, and the geometry of
the drive path alone: the coloured discs found in the zone mosaics against where they were
painted (median / largest distance; a calibration, pose or stitching bias shows here before
any road is extracted). Goal (issue 35): the median within 0.10 m on every drive.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import rasterio
import shapely
from pyproj import Transformer
from scipy.ndimage import center_of_mass, label
from sqlalchemy import create_engine, text

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from testkit.ipm_world import MARKER_RADIUS_M, VARIED, World, write  # noqa: E402
from testkit.scratch import scratch_database  # noqa: E402

UGVMAP = [str(REPO / ".venv" / "bin" / "ugvmap")]
GOAL_M = 0.10


def run(args: list[str], env: dict[str, str]) -> None:
    """One ``ugvmap`` command; its output on failure."""
    done = subprocess.run(UGVMAP + args, env=env, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"ugvmap {' '.join(args[:2])} failed:\n{done.stdout}{done.stderr}")


def centreline_offsets(url: str, world: World) -> tuple[np.ndarray, list[float]]:
    """Signed distance (m) of the stored network's points (every 0.1 m) from the true centre
    line, and the segments' widths."""
    engine = create_engine(url)
    with engine.connect() as conn:
        rows = conn.execute(text(
            "SELECT ST_AsBinary(ST_Segmentize(geom::geography, 0.1)::geometry), width_m "
            "FROM road_segments")).all()
    engine.dispose()
    xy = np.vstack([shapely.get_coordinates(shapely.from_wkb(bytes(r[0]))) for r in rows])
    x, y = world.local(xy[:, 0], xy[:, 1])
    return world.signed_offset_m(np.asarray(x), np.asarray(y)), [r[1] for r in rows]


def marker_errors(zones: Path, world: World) -> np.ndarray:
    """Distance (m) from each whole coloured disc found in the zone mosaics (saturated
    pixels, at least 60 % of a disc's area) to the nearest painted one."""
    truth = world.markers()
    out = []
    for zone in sorted(zones.glob("zone_*.tif")):
        with rasterio.open(zone) as ds:
            pixels, transform = ds.read(), ds.transform
            to_lonlat = Transformer.from_crs(ds.crs, "EPSG:4326", always_xy=True)
        rgb = pixels[:3].astype(int)
        blobs, count = label((rgb.max(axis=0) - rgb.min(axis=0) > 110) & (pixels[3] > 0))
        whole = 0.6 * np.pi * (MARKER_RADIUS_M / abs(transform.a)) ** 2
        for k in range(1, count + 1):
            blob = blobs == k
            if blob.sum() < whole:
                continue
            row, col = center_of_mass(blob)
            lon, lat = to_lonlat.transform(*(transform * (col + 0.5, row + 0.5)))
            x, y = world.local(np.array([lon]), np.array([lat]))
            out.append(float(np.hypot(truth[:, 0] - x[0], truth[:, 1] - y[0]).min()))
    return np.array(out)


def measure(name: str, frames: int | None) -> dict[str, float]:
    """Render drive ``name``, ingest it and its roads, score the centreline."""
    world, mount = VARIED[name]
    with tempfile.TemporaryDirectory() as tmp, scratch_database("ugvmap_bench_ipmc") as url:
        folder = Path(tmp)
        start = time.perf_counter()
        paths = write(folder, world, mount, frames=frames)
        rendered = time.perf_counter() - start
        env = {**os.environ, "DATABASE_URL": url, "UGVMAP_RASTER_STORE": str(folder / "store"),
               "UGVMAP_LOG_LEVEL": "WARNING", "PYTHONPATH": str(REPO)}
        run(["ingest", "ipm", str(paths["frames"]), "--poses", str(paths["poses"]),
             "--calib", str(paths["calib"]), "--layer", "drive", "--zones-dir",
             str(folder / "zones")], env)
        run(["ingest", "roads", "--layer", "drive", "--network", "drive"], env)
        offsets, widths = centreline_offsets(url, world)
        markers = marker_errors(folder / "zones", world)
    error = np.abs(offsets)
    return {"median": float(np.median(error)), "max": float(error.max()),
            "markers": len(markers),
            "marker_median": float(np.median(markers)) if len(markers) else np.nan,
            "marker_max": float(markers.max()) if len(markers) else np.nan,
            "signed": float(np.median(offsets)), "width": float(np.median(widths)),
            "true_width": world.width_m, "rendered_s": rendered}


def main() -> None:
    """Every drive (or ``--only`` some), one line each, then the verdict."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=sorted(VARIED), default=sorted(VARIED))
    parser.add_argument("--frames", type=int, help="at most this many frames per drive")
    args = parser.parse_args()
    print(f"{'drive':18} {'median':>7} {'max':>6} {'signed':>7} {'width':>6} {'true':>5}  "
          "markers: n median max")
    worst = 0.0
    for name in args.only:
        r = measure(name, args.frames)
        worst = max(worst, r["median"])
        print(f"{name:18} {r['median']:7.3f} {r['max']:6.3f} {r['signed']:+7.3f} "
              f"{r['width']:6.2f} {r['true_width']:5.2f}  {r['markers']:9.0f} "
              f"{r['marker_median']:6.3f} {r['marker_max']:5.3f}", flush=True)
    print(f"worst median {worst:.3f} m (goal <= {GOAL_M} m on every drive: "
          f"{'met' if worst <= GOAL_M else 'MISSED'})")


if __name__ == "__main__":
    main()
