"""Lanes from the paint, stored and mapped, on the synthetic multi-lane drive: frames -> IPM
mosaic (``ingest ipm``) -> ``ingest lanes`` over a network -> ``export network --format
lanelet2`` -> the official lanelet2 library, against the painted truth.

    .venv/bin/python bench/lane_maps.py [--frames 36] [--lanes 3.5,3.0,3.25,3.75 --forward 2]
        [--turn-lane-at 10]

Two networks over the same layer: ``truth`` (the road's true centre, imported) and
``extracted`` (``ingest roads`` with defaults on the drive's layer). For each: the stored lane
ranges, the lanelets lanelet2 loads (errors must be none), each lanelet's width (median across
its centreline) against the painted lane it lies in (found by where its middle is across the
road), the share of lanelet length within 0.15 m of the truth (issue 35: all within 0.15 m),
and lane changes: a lanelet side has a routing-graph neighbour exactly where the painted line
there is dashed (between lanes of one direction; never across the solid centre or an edge).
With ``--turn-lane-at M`` a 3 m turning lane opens on the right M metres along the drive over
a 15 m taper: a lanelet's width is compared with the paint's at each point of its centreline
(the turning lane's widening along the taper), and the rightmost through lane has the turning
lane as its right neighbour where the turning lane is beside it.
Every ``ugvmap`` step runs as its own process, as a user runs it (seconds given).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
# bench/lanelet2.py would shadow the lanelet2 library: the repository root, not bench/.
sys.path[0] = str(REPO)

from lanelet2 import core, geometry, io, projection, routing, traffic_rules  # noqa: E402

from app.lanelet2.export import PROJECTOR_FILE  # noqa: E402
from ingest.ipm.synthetic import Camera, Drive, LanePaint, frame_times, write_drive  # noqa: E402
from testkit.scratch import scratch_database  # noqa: E402

PAINT = LanePaint()
DRIVE = Drive.in_lane(PAINT)
"""The drive (``--lanes``/``--forward`` paint another road, driven in its leftmost forward
lane)."""
UGVMAP = [str(REPO / ".venv" / "bin" / "python"), "-m", "cli"]


def ugvmap(args: list[str], env: dict[str, str]) -> tuple[float, str]:
    """Run one ``ugvmap`` command as its own process: (seconds, what it printed)."""
    start = time.perf_counter()
    done = subprocess.run([*UGVMAP, *args], env=env, capture_output=True, text=True, cwd=REPO)
    if done.returncode:
        raise SystemExit(f"ugvmap {' '.join(args)} failed:\n{done.stdout}{done.stderr}")
    return time.perf_counter() - start, done.stdout


def truth_road(folder: Path, frames: int) -> Path:
    """The road's true centre along the drive (5 m either side of it) as GeoJSON."""
    radius = DRIVE.radius_m + DRIVE.road_offset_m
    driven = frames / 7 * DRIVE.speed_mps
    az = np.radians(DRIVE.start_deg) + np.linspace(-5, driven + 5, 80) / DRIVE.radius_m
    lon, lat = DRIVE.to_lonlat(radius * np.sin(az), radius * np.cos(az))
    path = folder / "road.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {},
        "geometry": {"type": "LineString",
                     "coordinates": np.column_stack([lon, lat]).tolist()}}]}))
    return path


TURN = -1
"""The turning lane's number, right of lane 0."""


def painted_lane(east: float, north: float) -> tuple[int, float] | None:
    """The painted lane (0 = the rightmost in the drive's direction, :data:`TURN` the turning
    lane) at a point (the drive's local metres) and its painted width there, or None off the
    road (the bend's centre is on the right: inwards)."""
    radius_m = float(np.hypot(east, north))
    b = PAINT.boundaries_m()
    edges = DRIVE.radius_m + DRIVE.road_offset_m - b[-1] / 2 + b
    out = float(PAINT.turn_out_m(float(DRIVE.along_m(np.arctan2(east, north)))))
    if out > 0 and edges[0] - out <= radius_m < edges[0]:
        return TURN, out
    for i in range(len(edges) - 1):
        if edges[i] <= radius_m < edges[i + 1]:
            return i, PAINT.widths_m[i]
    return None


def _beside(lane: int, other: int, along_m: float) -> bool:
    """Whether the painted line between ``lane`` and the lane ``other`` is dashed there (a
    lane change allowed): a lane line between lanes of one direction, or the turning lane's
    line where the turning lane is beside the rightmost lane."""
    if TURN in (lane, other):
        return PAINT.turn_at_m is not None and min(lane, other) == TURN and \
            max(lane, other) == 0 and along_m >= PAINT.turn_at_m
    between = max(lane, other)  # the boundary index between the two lanes
    return 0 < between < len(PAINT.widths_m) and \
        PAINT.line_kind(between)[0] == "dashed" and 0 <= other < len(PAINT.widths_m)


def scores(osm: Path) -> dict[str, float]:
    """The exported map as lanelet2 loads it, against the paint (see the module docstring)."""
    info = yaml.safe_load((osm.parent / PROJECTOR_FILE).read_text())
    origin = io.Origin(info["map_origin"]["latitude"], info["map_origin"]["longitude"])
    proj = projection.UtmProjector(origin)
    lanelet_map, errors = io.loadRobust(str(osm), proj)
    rules = traffic_rules.create(traffic_rules.Locations.Germany,
                                 traffic_rules.Participants.Vehicle)
    graph = routing.RoutingGraph(lanelet_map, rules)
    width_err, lengths, sides_ok, sides = [], [], 0, 0
    def local(point: Any) -> tuple[float, float]:
        gps = proj.reverse(core.BasicPoint3d(point.x, point.y, 0.0))
        return DRIVE.to_local(gps.lon, gps.lat)

    for ll in lanelet_map.laneletLayer:
        c = ll.centerline
        mid = c[len(c) // 2]
        found = painted_lane(*local(mid))
        if found is None:
            continue
        lane = found[0]
        inner = [c[i] for i in range(1, len(c) - 1)] or [mid]
        # Against the paint at each point: a turning lane widens along its taper.
        painted = [(painted_lane(*local(p)) or found)[1] for p in inner]
        width_err.append(abs(float(np.median([
            geometry.distance(ll.leftBound, p) + geometry.distance(ll.rightBound, p) - w
            for p, w in zip(inner, painted, strict=True)]))))
        lengths.append(geometry.length2d(ll))
        along = float(DRIVE.along_m(np.arctan2(*local(mid))))
        # Seen along the lanelet, its left is the next lane inwards for a forward (drive
        # direction) lane, outwards for a backward one: which painted line lies there.
        forward = lane < PAINT.forward
        for side, other in (("left", lane + 1 if forward else lane - 1),
                            ("right", lane - 1 if forward else lane + 1)):
            sides += 1
            sides_ok += (getattr(graph, side)(ll) is not None) == _beside(lane, other, along)
    err, length = np.array(width_err), np.array(lengths)
    return {"errors": len(errors), "lanelets": len(length),
            "width_median": float(np.median(err)), "width_max": float(err.max()),
            "within": float(length[err <= 0.15].sum() / length.sum()),
            "changes": sides_ok / max(sides, 1)}


def main() -> None:
    """Render the drive, make both networks, ingest their lanes, export and score."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=36)
    parser.add_argument("--lanes", help="lane widths from the right edge, e.g. 3.0,3.75,3.25")
    parser.add_argument("--forward", type=int, help="lanes in the drive's direction")
    parser.add_argument("--turn-lane-at", type=float, metavar="M",
                        help="a turning lane opening on the right M metres along the drive")
    args = parser.parse_args()
    global PAINT, DRIVE
    widths, forward = PAINT.widths_m, PAINT.forward
    if args.lanes:
        widths = tuple(float(w) for w in args.lanes.split(","))
        forward = args.forward or (len(widths) + 1) // 2
    PAINT = LanePaint(widths, forward, turn_at_m=args.turn_lane_at)
    DRIVE = Drive.in_lane(PAINT, forward - 1)
    with tempfile.TemporaryDirectory() as tmp, scratch_database("ugvmap_bench_lane_maps") as url:
        folder = Path(tmp)
        paths = write_drive(folder, DRIVE, Camera(), frame_times(args.frames))
        env = {**os.environ, "DATABASE_URL": url, "UGVMAP_RASTER_STORE": str(folder / "store"),
               "UGVMAP_LOG_LEVEL": "WARNING"}
        ugvmap(["ingest", "ipm", str(paths["frames"]), "--poses", str(paths["poses"]),
                "--calib", str(paths["calib"]), "--layer", "drive"], env)
        ugvmap(["ingest", "network", str(truth_road(folder, args.frames)), "--network",
                "truth"], env)
        ugvmap(["ingest", "roads", "--layer", "drive", "--network", "extracted"], env)
        turn = "" if PAINT.turn_at_m is None else \
            f", a {PAINT.turn_width_m:g} m turning lane from {PAINT.turn_at_m:g} m along " \
            f"over a {PAINT.turn_taper_m:g} m taper"
        print(f"synthetic drive: {args.frames} frames, {PAINT.forward}+"
              f"{len(PAINT.widths_m) - PAINT.forward} lanes {PAINT.widths_m} m{turn}, "
              "ingest ipm defaults; 2 shared cores")
        for network in ("truth", "extracted"):
            seconds, said = ugvmap(["ingest", "lanes", "--layer", "drive", "--network",
                                    network], env)
            osm = folder / f"{network}.osm"
            ugvmap(["export", "network", network, "--format", "lanelet2", "--out", str(osm)],
                   env)
            r = scores(osm)
            print(f"{network}: ingest lanes {seconds:.1f} s: {' / '.join(said.splitlines())}")
            print(f"  lanelet2: {r['errors']} load errors, {r['lanelets']} lanelets on the "
                  f"road; width error median {r['width_median']:.3f} m, max "
                  f"{r['width_max']:.3f} m; {r['within']:.1%} of lanelet length within "
                  f"0.15 m (goal 100 %: {'met' if r['within'] == 1.0 else 'MISSED'}); "
                  f"lane changes right on {r['changes']:.1%} of lanelet sides")


if __name__ == "__main__":
    main()
