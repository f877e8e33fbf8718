"""Lane markings: the synthetic multi-lane drive (frames -> IPM mosaic -> markings -> lanes
across the road) against its painted truth, and the real images of ../shared/data/lanes.

    .venv/bin/python bench/lanes.py [--skip-drive] [--skip-real] [--frames 36]

Synthetic (``ingest.ipm.synthetic``'s :class:`LanePaint` road, 2+2 lanes of 3.5/3.0/3.25/3.75 m,
the vehicle in the left forward lane; every default of ``ingest ipm`` and ``extract-lanes``):
marking precision / recall at 0.25 m (length-weighted), boundary position (distance from each
painted line to the nearest extracted one: median / p95), solid/dashed correct (share of the
found length whose kind is right), lane count and widths (+-0.15 m) right across the road
every 0.5 m of the seen arc: of the cuts themselves (:func:`ingest.lanes.across.sections`),
of those whose whole painted cross-section lies in the coverage (less 1 m), and of the lane
ranges a segment stores (:func:`ingest.lanes.assign.lane_ranges`: what ``ingest lanes`` keeps
and the Lanelet2 map is drawn from) at every cut. Goals (issue 35): P/R >= 0.95/0.95, median
<= 0.05 m, p95 <= 0.15 m, kinds >= 95 %, lanes >= 95 % (the stored lanes' figure decides).

Real: the OpenSatMap satellite patches (~0.14 m/px, lane lines and road edges as polylines:
every extracted line but ``other`` and ``crosswalk`` is scored) and the RoadMarking drone
crops (~0.03 m/px, only dashed lane lines labelled: the extracted dashes are scored against
the label mask's centre lines), precision / recall at 0.5 m and seconds per megapixel, per
image and mean.
Aim: >= 0.80 / 0.75. Baseline in the same run: the top-hat paint mask alone, thinned (what the
line tracing and classification add or cost).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import shapely
from pyproj import Transformer

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ingest.ipm.job import ingest_ipm  # noqa: E402
from ingest.ipm.synthetic import Camera, Drive, LanePaint, frame_times, write_drive  # noqa: E402
from ingest.lanes.across import Section, frame_at, sections  # noqa: E402
from ingest.lanes.assign import LaneRange, Paint, lane_ranges  # noqa: E402
from ingest.lanes.extract import extract_markings, rgb_of  # noqa: E402
from ingest.lanes.paint import brightness, paint_mask, top_hat  # noqa: E402
from ingest.lanes.road import model_road  # noqa: E402
from ingest.roads.evaluate import buffer_scores, rasterize_lines  # noqa: E402
from ingest.roads.georef import read_image  # noqa: E402
from ingest.roads.skeleton import thin  # noqa: E402
from testkit.scratch import scratch_database  # noqa: E402

LANES = LanePaint()
DRIVE = Drive.in_lane(LANES)

DATA = REPO.parent / "shared" / "data" / "lanes"
DASHLINE = 3  # roadmarking_label.txt: 0 background, 1 arrow, 2 right_arrow, 3 dashline


def score(pred: np.ndarray, gt: np.ndarray, res: float, within_m: float) -> tuple[float, float]:
    """Buffer precision / recall of two one-pixel line rasters."""
    s = buffer_scores(pred, gt, [within_m / res], res)[0]
    return s.precision, s.recall


def real_rows(within_m: float = 0.5) -> list[dict]:
    """Per real image: precision / recall of the markings and of the baseline, s/MP."""
    rows = []
    for folder in ("opensatmap_internvl_fork", "roadmarking_semianno_uav"):
        pairs = DATA / folder / "pairs.json"
        if not pairs.exists():
            print(f"skipped {folder}: {pairs} absent")
            continue
        for pair in json.loads(pairs.read_text()):
            img = read_image(DATA / folder / pair["image"], pair["m_per_px"])
            shape = img.pixels.shape[:2]
            start = time.perf_counter()
            found = extract_markings(img, road=model_road(img))
            seconds = time.perf_counter() - start
            label = DATA / folder / pair["label"]
            hat = top_hat(brightness(rgb_of(img.pixels)), img.resolution_m, None)
            baseline = thin(paint_mask(hat))
            if label.suffix == ".json":
                gt = rasterize_lines([np.asarray(line, float)
                                      for line in json.loads(label.read_text())], shape)
                pred = rasterize_lines([m.coords for m in found
                                        if m.kind not in ("other", "crosswalk")], shape)
            else:
                gt = thin(cv2.imread(str(label), cv2.IMREAD_GRAYSCALE) == DASHLINE)
                pred = rasterize_lines([p.coords for m in found if m.kind == "dashed"
                                        for p in m.members], shape)
            p, r = score(pred, gt, img.resolution_m, within_m)
            bp, br = score(baseline, gt, img.resolution_m, within_m)
            rows.append({"image": f"{folder[:10]}/{pair['image']}", "p": p, "r": r,
                         "base_p": bp, "base_r": br,
                         "s_per_mp": seconds / (shape[0] * shape[1] / 1e6)})
    return rows


def print_real(rows: list[dict]) -> None:
    """The real images' table, its mean and the verdict against the aim."""
    print(f"{'real image':42} {'P@0.5m':>7} {'R@0.5m':>7} {'base P':>7} {'base R':>7} "
          f"{'s/MP':>6}")
    for row in rows:
        print(f"{row['image']:42} {row['p']:7.3f} {row['r']:7.3f} {row['base_p']:7.3f} "
              f"{row['base_r']:7.3f} {row['s_per_mp']:6.2f}")
    if not rows:
        return
    mean: dict[str, float] = {}
    for name in [*sorted({row["image"].split("/")[0] for row in rows}), "all"]:
        some = [row for row in rows if name == "all" or row["image"].startswith(name + "/")]
        mean = {k: float(np.mean([row[k] for row in some]))
                for k in ("p", "r", "base_p", "base_r", "s_per_mp")}
        print(f"{'mean, ' + name:42} {mean['p']:7.3f} {mean['r']:7.3f} {mean['base_p']:7.3f} "
              f"{mean['base_r']:7.3f} {mean['s_per_mp']:6.2f}")
    met = mean["p"] >= 0.8 and mean["r"] >= 0.75
    print(f"aim P >= 0.80, R >= 0.75 (all): {'met' if met else 'MISSED'}")


def drive_markings(frames: int) -> tuple[list[Paint], shapely.Geometry, float]:
    """Render the drive, stitch it with ``ingest ipm``'s defaults, extract each zone's
    markings: (the markings in the drive's local metres, the coverage, seconds of extraction
    per megapixel)."""
    out: list[Paint] = []
    cover, seconds, pixels = [], 0.0, 0
    with tempfile.TemporaryDirectory() as tmp, scratch_database("ugvmap_bench_lanes") as url:
        folder = Path(tmp)
        paths = write_drive(folder, DRIVE, Camera(), frame_times(frames))
        zones = folder / "zones"
        ingest_ipm(paths["frames"], "lanes", paths["calib"], paths["poses"], zones_dir=zones,
                   database_url=url, store=folder / "store")
        for zone in sorted(zones.glob("zone_*.tif")):
            img = read_image(zone)
            assert img.transform is not None and img.crs is not None
            to_lonlat = Transformer.from_crs(img.crs, "EPSG:4326", always_xy=True)
            start = time.perf_counter()
            found = extract_markings(img, road=model_road(img))
            seconds += time.perf_counter() - start
            pixels += img.pixels.shape[0] * img.pixels.shape[1]

            def local(xy: np.ndarray, t: Transformer = to_lonlat, a=img.transform) -> np.ndarray:
                lon, lat = t.transform(*(a * (xy[:, 0], xy[:, 1])))
                return np.column_stack(DRIVE.to_local(np.asarray(lon), np.asarray(lat)))

            out += [Paint(shapely.LineString(local(m.coords)), m.kind, m.colour, m.width_m,
                          m.confidence) for m in found
                    if m.kind not in ("other", "crosswalk")]
            valid = img.valid if img.valid is not None else np.ones(img.pixels.shape[:2], bool)
            contours, _ = cv2.findContours(valid.astype(np.uint8), cv2.RETR_EXTERNAL,
                                           cv2.CHAIN_APPROX_SIMPLE)
            cover += [shapely.Polygon(local(c[:, 0, :].astype(float))).buffer(0)
                      for c in contours if len(c) >= 3]
    return out, shapely.union_all(cover), seconds / (pixels / 1e6)


def truth_lines() -> list[tuple[shapely.LineString, str]]:
    """The painted marking lines (local metres) and their kinds."""
    out = []
    for f in DRIVE.truth()["features"]:
        if f["properties"]["feature"] == "marking":
            lonlat = np.asarray(f["geometry"]["coordinates"])
            xy = np.column_stack(DRIVE.to_local(lonlat[:, 0], lonlat[:, 1]))
            out.append((shapely.LineString(xy), f["properties"]["kind"]))
    return out


def samples(lines: list[tuple[shapely.LineString, str]], inside: shapely.Geometry,
            step: float = 0.05) -> tuple[np.ndarray, list[str]]:
    """Points every ``step`` m along the lines' parts inside ``inside``, and their kinds."""
    pts, kinds = [], []
    for line, kind in lines:
        part = line.intersection(inside)
        for piece in getattr(part, "geoms", [part]):
            if piece.is_empty or piece.length == 0:
                continue
            at = shapely.line_interpolate_point(piece, np.arange(0, piece.length, step))
            pts.append(shapely.get_coordinates(at))
            kinds += [kind] * len(at)
    return (np.vstack(pts) if pts else np.zeros((0, 2))), kinds


def nearest(points: np.ndarray, lines: list[tuple[shapely.LineString, str]]
            ) -> tuple[np.ndarray, list[str]]:
    """Distance from each point to the nearest of ``lines``, and that line's kind."""
    if not lines or not len(points):
        return np.full(len(points), np.inf), [""] * len(points)
    geoms = np.array([line for line, _ in lines])
    tree = shapely.STRtree(geoms)
    pts = shapely.points(points)
    idx = tree.nearest(pts)
    return shapely.distance(pts, geoms[idx]), [lines[i][1] for i in idx]


def cross_section(path: shapely.LineString, station_m: float,
                  truth: list[tuple[shapely.LineString, str]]) -> shapely.LineString:
    """The painted road across ``path`` at ``station_m``: from the first painted line the cut
    meets to the last (empty when it meets none)."""
    centre, left = frame_at(path, station_m)
    cut = shapely.LineString([centre - 15 * left, centre + 15 * left])
    met = shapely.get_coordinates(shapely.intersection(
        shapely.union_all([line for line, kind in truth if kind != "stop_line"]), cut))
    if len(met) < 2:
        return shapely.LineString()
    along = (met - centre) @ left
    return shapely.LineString([met[along.argmin()], met[along.argmax()]])


WANT = list(LANES.widths_m)


def right_share(cuts: list[Section], ranges: list[LaneRange] | None = None) -> float:
    """Share of ``cuts`` whose lanes (the cut's own, or with ``ranges`` the stored range's at
    its station) are the painted ones: count each way and every width within 0.15 m."""
    right = 0
    for cut in cuts:
        if ranges is None:
            forward, backward = (len(side) for side in cut.lanes())
            widths = [w for side in cut.lanes() for w in side]
        else:
            r = next((r for r in ranges if r.station_from_m <= cut.station_m <= r.station_to_m),
                     None)
            forward, backward, widths = (0, 0, []) if r is None else (r.forward, r.backward,
                                                                      r.widths)
        right += (forward == LANES.forward and backward == len(WANT) - LANES.forward
                  and all(abs(a - b) <= 0.15 for a, b in zip(widths, WANT, strict=True)))
    return right / max(len(cuts), 1)


def drive_scores(frames: int) -> dict[str, float]:
    """The synthetic drive's figures (see the module docstring)."""
    paint, cover, s_per_mp = drive_markings(frames)
    found = [(p.line, p.kind) for p in paint]
    inside = cover.buffer(-1.0)
    truth = truth_lines()
    t_pts, t_kinds = samples(truth, inside)
    f_pts, _ = samples(found, inside)
    to_found, found_kind = nearest(t_pts, found)
    to_truth, _ = nearest(f_pts, truth)
    near = to_found <= 0.25
    lines = [k != "stop_line" for k in t_kinds]
    dashed = np.array([k == "dashed" for k in t_kinds])
    said_dashed = np.array([k == "dashed" for k in found_kind])
    kind_ok = (dashed == said_dashed)[near & np.array(lines)]
    ring = np.arange(0.0, 2 * np.pi * DRIVE.radius_m, 0.5)  # once round: no cut counted twice
    xy = np.column_stack(DRIVE.local_pose(ring)[:2])
    path = shapely.LineString([*xy, xy[0]])  # closed: the drive's start is no end of the road
    seen = [c for c in sections(path, found) if inside.contains(path.interpolate(c.station_m))]
    across = [c for c in seen if inside.contains(cross_section(path, c.station_m, truth))]
    ranges = lane_ranges(path, paint)
    boundary = to_found[np.array(lines)]
    return {"precision": float((to_truth <= 0.25).mean()) if len(to_truth) else 0.0,
            "recall": float(near.mean()) if len(near) else 0.0,
            "median": float(np.median(boundary)), "p95": float(np.percentile(boundary, 95)),
            "kinds": float(kind_ok.mean()) if len(kind_ok) else 0.0,
            "lanes": right_share(seen), "lanes_across": right_share(across),
            "stored": right_share(seen, ranges), "stations": len(seen),
            "stations_across": len(across),
            "seen_m": float(cover.area), "s_per_mp": s_per_mp}


def print_drive(r: dict[str, float], frames: int) -> None:
    """The synthetic drive's figures with their verdicts."""
    def verdict(ok: bool) -> str:
        return "met" if ok else "MISSED"

    print(f"synthetic drive ({frames} frames, 2+2 lanes {LANES.widths_m}, defaults): "
          f"{r['stations']} cuts, {r['s_per_mp']:.2f} s/MP")
    print(f"  marking P/R @0.25 m: {r['precision']:.3f} / {r['recall']:.3f} "
          f"(goal 0.95/0.95: {verdict(r['precision'] >= 0.95 and r['recall'] >= 0.95)})")
    print(f"  boundary position: median {r['median']:.3f} m, p95 {r['p95']:.3f} m "
          f"(goal 0.05/0.15: {verdict(r['median'] <= 0.05 and r['p95'] <= 0.15)})")
    print(f"  solid/dashed right on {r['kinds']:.1%} of the found length "
          f"(goal 95 %: {verdict(r['kinds'] >= 0.95)})")
    print(f"  lane count and widths (+-0.15 m) right: stored lanes {r['stored']:.1%} of the "
          f"cuts (goal 95 %: {verdict(r['stored'] >= 0.95)}); the cuts themselves "
          f"{r['lanes']:.1%}, {r['lanes_across']:.1%} of the {r['stations_across']} whose "
          "whole road is in the coverage")


def main() -> None:
    """Run the synthetic drive, then the real images (each skippable)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-drive", action="store_true")
    parser.add_argument("--skip-real", action="store_true")
    parser.add_argument("--frames", type=int, default=36)
    args = parser.parse_args()
    if not args.skip_drive:
        print_drive(drive_scores(args.frames), args.frames)
    if not args.skip_real:
        print_real(real_rows())


if __name__ == "__main__":
    main()
