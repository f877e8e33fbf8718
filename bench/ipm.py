"""IPM ingest throughput (frames/s for 2048x1024 panoramas), peak memory, and blend quality.

    .venv/bin/python bench/ipm.py [--frames 420] [--skip-blend]

Throughput: a synthetic drive of ``--frames`` 2048x1024 JPEG panoramas (7 Hz, 10 m/s, a long
bend; a dozen rendered frames repeat, which costs the pipeline exactly what distinct frames
do) through ``ingest_ipm`` into a scratch database, each configuration in its own process
so its peak RSS is its own:

* ``ugvmap (2 workers)``: the default; frames/s of the frame phase (decode, IPM, stitch, zone
  files) and of the whole job (+ zone COGs and registration);
* ``ugvmap, half the drive``: the same on the first half, to show peak memory does not grow
  with the drive (zones are written and freed as the vehicle leaves them);
* ``ugvmap (1 worker)``;
* ``ugvmap, 4096/8192 px zones``: other zone sizes (the COG step's cost follows the zones'
  area, the frame phase's does not);
* baseline ``naive per-frame lookup``: the same IPM with the ground -> panorama lookup
  recomputed for every frame (what a straightforward implementation does), against
  ``precomputed lookup`` in the same sequential loop.

Each configuration runs ``--repeat`` times (rounds over all of them) and its fastest run
counts: other jobs share the machine, and a load spike should not decide a comparison.

Goal (issue 11): >= 7 frames/s (the camera's rate) on this 2-core machine.

Blend quality (``--skip-blend`` to skip): the 1024x512 synthetic drive of the tests with known
ground truth, stitched with each blend mode, with exact poses and with noisy poses (3 cm,
0.3°): NCC against the truth after a light blur, and without blur (sharpness).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ingest.ipm.synthetic import Camera, Drive, frame_times, write_drive  # noqa: E402

GOAL_FPS = 7.0
BENCH_DRIVE = Drive(radius_m=400.0, speed_mps=10.0, markers=())
BENCH_CAMERA = Camera(image_size=(2048, 1024))
DISTINCT_FRAMES = 12
BASELINE_FRAMES = 100


def peak_rss_mib() -> float:
    """This process's peak RSS (VmHWM: ru_maxrss would survive fork+exec)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def make_drive(folder: Path, count: int) -> dict[str, Path]:
    """2048x1024 frames (a dozen rendered, repeated), 20 Hz poses, calibration and mask."""
    paths = write_drive(folder, BENCH_DRIVE, BENCH_CAMERA, frame_times(DISTINCT_FRAMES),
                        supersample=1)
    times = frame_times(count)
    with open(paths["frames"] / "frames.csv", "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["t", "file"])
        for i, t in enumerate(times):
            out.writerow([f"{t:.6f}", f"frame_{i % DISTINCT_FRAMES:05d}.jpg"])
    pose_t = np.arange(0.0, float(times[-1]) + 1.0, 0.05)
    lon, lat, heading = BENCH_DRIVE.pose(pose_t)
    with open(paths["poses"], "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["t", "lon", "lat", "heading_deg"])
        out.writerows(zip(pose_t, lon, lat, heading, strict=True))
    return paths


def run_job(folder: Path, frames: int, workers: int = 2, share: float = 1.0,
            zone_px: int = 2048) -> dict:
    """Child: the real job into a scratch database; frame phase and total frames/s."""
    from ingest.ipm.job import IpmOptions, ingest_ipm
    from testkit.scratch import scratch_database

    options = IpmOptions(workers=workers, frames=slice(0, round(frames * share)),
                         zone_size_px=(zone_px, zone_px))
    with scratch_database("ugvmap_bench_ipm") as url, tempfile.TemporaryDirectory() as store:
        summary = ingest_ipm(folder / "frames", "bench-ipm", folder / "calib.json",
                             folder / "poses.csv", options=options, database_url=url,
                             store=Path(store))
    return {"frames": summary.used, "frames_s": summary.frames_seconds,
            "total_s": summary.total_seconds, "zones": summary.zones_written,
            "buffer_mib": summary.peak_buffer_bytes / 2**20,
            "area_m2": summary.area_m2, "peak_rss_mib": peak_rss_mib()}


def run_sequential(folder: Path, naive: bool) -> dict:
    """Child: one thread, frame by frame; ``naive`` recomputes the lookup for every frame."""
    from ingest.ipm.calibration import load_calibration
    from ingest.ipm.frames import decode_image
    from ingest.ipm.grid import ZoneGrid
    from ingest.ipm.lookup import build_lookup, sample_patch
    from ingest.ipm.place import place
    from ingest.ipm.poses import interpolate_poses, read_poses
    from ingest.ipm.stitch import ZoneStitcher

    calib = load_calibration(folder / "calib.json")
    track = read_poses(folder / "poses.csv")
    with open(folder / "frames" / "frames.csv", newline="") as f:
        rows = list(csv.DictReader(f))[:BASELINE_FRAMES]
    poses = interpolate_poses(track, np.array([float(r["t"]) for r in rows]), 0.5)
    grid = ZoneGrid(float(track.lon[0]), float(track.lat[0]))
    with tempfile.TemporaryDirectory() as out:
        stitcher = ZoneStitcher(grid, "nearest", Path(out), 30 / 0.06)
        start = time.perf_counter()
        lookup = None
        for row, pose in zip(rows, poses, strict=True):
            image = decode_image((folder / "frames" / row["file"]).read_bytes(), row["file"])
            if lookup is None or naive:
                lookup = build_lookup(calib, 30.0, 0.06, 15.0)
            gp = grid.to_grid([pose.lon], [pose.lat], [pose.heading_deg])[0]
            placed = place(sample_patch(image, lookup), lookup.window, gp, 0.06)
            stitcher.add(placed)
            stitcher.close_far(gp.col, gp.row)
        stitcher.close_all()
        seconds = time.perf_counter() - start
    return {"frames": len(rows), "frames_s": seconds, "peak_rss_mib": peak_rss_mib()}


#: Configuration -> keyword arguments of :func:`run_job` (or sequential loops).
CONFIGS: dict[str, dict] = {
    "ugvmap (2 workers)": {},
    "ugvmap, half the drive": {"share": 0.5},
    "ugvmap (1 worker)": {"workers": 1},
    "ugvmap, 4096 px zones": {"zone_px": 4096},
    "ugvmap, 8192 px zones": {"zone_px": 8192},
    "precomputed lookup, sequential": {"naive": False},
    "naive per-frame lookup, sequential (baseline)": {"naive": True},
}


def child(config: str, folder: Path, frames: int) -> dict:
    """Run one configuration in this (child) process, so its peak RSS is its own."""
    kwargs = CONFIGS[config]
    if "naive" in kwargs:
        return run_sequential(folder, **kwargs)
    return run_job(folder, frames, **kwargs)


def throughput(frames: int, repeat: int) -> None:
    """Print frames/s, buffers and peak RSS of every configuration against the goal and the
    naive baseline, each the fastest of ``repeat`` rounds."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        start = time.perf_counter()
        make_drive(folder, frames)
        print(f"drive: {frames} frames of 2048x1024 JPEG at 7 Hz, 10 m/s "
              f"({frames / 7 * 10:.0f} m), window 30 m at 0.06 m/px, zones 2048 px "
              f"(rendered in {time.perf_counter() - start:.0f} s); 2 shared cores, noisy")
        results: dict[str, dict] = {}
        for _ in range(repeat):  # rounds over all configurations: load spikes hit each alike
            for config in CONFIGS:
                out = subprocess.run([sys.executable, __file__, "--child", config, str(folder),
                                      str(frames)], capture_output=True, text=True, check=True)
                run = json.loads(out.stdout.strip().splitlines()[-1])
                best = results.get(config)
                if best is None or run["frames_s"] < best["frames_s"]:
                    results[config] = run
    baseline = results["naive per-frame lookup, sequential (baseline)"]
    base_fps = baseline["frames"] / baseline["frames_s"]
    print(f"{'configuration':46} {'frames':>6} {'frames/s':>8} {'vs goal':>7} "
          f"{'vs baseline':>11} {'job fr/s':>8} {'zones':>5} {'buffers':>8} {'peak RSS':>9}")
    for config, r in results.items():
        fps = r["frames"] / r["frames_s"]
        job = f"{r['frames'] / r['total_s']:8.1f}" if "total_s" in r else f"{'-':>8}"
        zones = f"{r['zones']:5d}" if "zones" in r else f"{'-':>5}"
        buffers = f"{r['buffer_mib']:5.0f} MiB" if "buffer_mib" in r else f"{'-':>8}"
        print(f"{config:46} {r['frames']:6d} {fps:8.1f} {fps / GOAL_FPS:6.2f}x "
              f"{fps / base_fps:10.2f}x {job} {zones} {buffers} {r['peak_rss_mib']:5.0f} MiB")
    main_run = results["ugvmap (2 workers)"]
    fps = main_run["frames"] / main_run["frames_s"]
    whole = main_run["frames"] / main_run["total_s"]
    mosaic_mib = main_run["area_m2"] / 0.06**2 * 7 / 2**20
    print(f"goal >= {GOAL_FPS} frames/s: frame phase {fps:.1f} ({fps / GOAL_FPS:.2f}x), "
          f"whole job incl. COGs {whole:.1f} ({whole / GOAL_FPS:.2f}x): "
          f"{'met' if whole >= GOAL_FPS else 'frame phase only' if fps >= GOAL_FPS else 'MISSED'}")
    print(f"memory: the drive's mosaic ({main_run['area_m2']:,.0f} m²) would need "
          f"{mosaic_mib:.0f} MiB of blend buffers at once; peak buffers "
          f"{main_run['buffer_mib']:.0f} MiB, peak RSS {main_run['peak_rss_mib']:.0f} MiB "
          f"(half the drive: {results['ugvmap, half the drive']['peak_rss_mib']:.0f} MiB)")


def truth_scores(zone_dir: Path, drive: Drive) -> tuple[float, float, float]:
    """(NCC after a 1.5 px blur, NCC unblurred, covered m²) of the zone mosaics vs truth."""
    import rasterio
    from pyproj import Transformer

    a_all, b_all, raw_a, raw_b, covered = [], [], [], [], 0
    for path in sorted(zone_dir.glob("zone_*.tif")):
        with rasterio.open(path) as ds:
            data, transform, crs = ds.read(), ds.transform, ds.crs
        opaque = data[3] == 255
        rows, cols = np.nonzero(opaque)
        to_lonlat = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
        truth = np.zeros((*opaque.shape, 3), np.float32)
        for dr in (0.25, 0.75):
            for dc in (0.25, 0.75):
                x, y = transform * (cols + dc, rows + dr)
                truth[rows, cols] += drive.texture(*drive.to_local(*to_lonlat.transform(x, y)))
        truth /= 4
        img = np.moveaxis(data[:3], 0, -1).astype(np.float32)
        weights = np.float32([0.299, 0.587, 0.114])
        inner = cv2.erode(opaque.astype(np.uint8), np.ones((11, 11), np.uint8)) > 0
        for src, dst, blur in ((img, a_all, True), (truth, b_all, True), (img, raw_a, False),
                               (truth, raw_b, False)):
            grey = src @ weights
            dst.append((cv2.GaussianBlur(grey, (0, 0), 1.5) if blur else grey)[inner])
        covered += int(inner.sum())

    def ncc(a: list, b: list) -> float:
        x, y = np.concatenate(a), np.concatenate(b)
        x, y = x - x.mean(), y - y.mean()
        return float((x * y).sum() / np.sqrt((x * x).sum() * (y * y).sum()))

    return ncc(a_all, b_all), ncc(raw_a, raw_b), covered * 0.06**2


def blend_quality() -> None:
    """Print how close each blend mode's mosaic is to the known ground, with exact and with
    noisy poses: the measurement behind the default ``nearest``."""
    from ingest.ipm.job import IpmOptions, ingest_ipm
    from testkit.scratch import scratch_database

    drive, camera = Drive(), Camera()
    with tempfile.TemporaryDirectory() as tmp, scratch_database("ugvmap_bench_ipm") as url:
        folder = Path(tmp)
        paths = write_drive(folder, drive, camera, frame_times(36))
        noisy = folder / "noisy.csv"
        rng = np.random.default_rng(7)
        with open(paths["poses"], newline="") as f:
            rows = list(csv.DictReader(f))
        metre_lat = 1 / 111_320
        metre_lon = metre_lat / np.cos(np.radians(drive.lat0))
        with open(noisy, "w", newline="") as f:
            out = csv.writer(f)
            out.writerow(["t", "lon", "lat", "heading_deg"])
            for r in rows:
                out.writerow([r["t"], float(r["lon"]) + rng.normal(0, 0.03) * metre_lon,
                              float(r["lat"]) + rng.normal(0, 0.03) * metre_lat,
                              float(r["heading_deg"]) + rng.normal(0, 0.3)])
        print("\nblend modes on the 1024x512 test drive (36 frames, window 20 m), NCC of the "
              "zone mosaics against the ground truth:")
        print(f"{'blend':9} {'poses':6} {'NCC blur 1.5 px':>15} {'NCC unblurred':>13} "
              f"{'covered m²':>10} {'frames/s':>8} {'buffers':>8}")
        for poses, label in ((paths["poses"], "exact"), (noisy, "noisy")):
            for blend in ("nearest", "later", "weighted"):
                zones = folder / f"{label}-{blend}"
                summary = ingest_ipm(paths["frames"], f"blend-{label}-{blend}", paths["calib"],
                                     poses, options=IpmOptions(window_m=20, blend=blend),
                                     zones_dir=zones, database_url=url, store=folder / "store")
                blurred, sharp, area = truth_scores(zones, drive)
                print(f"{blend:9} {label:6} {blurred:15.4f} {sharp:13.4f} {area:10.0f} "
                      f"{summary.used / summary.frames_seconds:8.1f} "
                      f"{summary.peak_buffer_bytes / 2**20:5.0f} MiB")


def main() -> None:
    """Command line entry point (see the module docstring); ``--child`` is the subprocess."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=420, help="frames in the drive")
    parser.add_argument("--repeat", type=int, default=2,
                        help="runs per configuration; the fastest counts (shared machine)")
    parser.add_argument("--skip-blend", action="store_true")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        os.environ.setdefault("UGVMAP_LOG_LEVEL", "WARNING")
        print(json.dumps(child(args.child[0], Path(args.child[1]), int(args.child[2]))))
        return
    throughput(args.frames, args.repeat)
    if not args.skip_blend:
        blend_quality()


if __name__ == "__main__":
    main()
