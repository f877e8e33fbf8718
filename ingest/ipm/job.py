"""The ``ingest ipm`` job: frames + poses + calibration -> zone mosaics -> an ipm-mosaic layer.

1. Everything that can be checked before reading frames is (calibration, poses, frames list,
   layer name, zone grid): a bad input is one line and nothing is written.
2. Frames are decoded, sampled (one ``cv2.remap`` through the drive's fixed lookup) and
   placed on the zone grid by worker threads (OpenCV releases the GIL); the main thread
   blends them into the open zones in drive order and writes each zone as soon as the
   vehicle has left it, so memory stays bounded however long the drive. A frame that cannot
   be used (unreadable, wrong size, no pose, pose gap, no QR code) is skipped and counted,
   never fatal: a bad frame late in a drive does not lose the zones before it.
3. The zone mosaics (GeoTIFF + ``.zone.json``, the survey's own format) go through the very
   same atomic path as ``ugvmap ingest raster --kind ipm-mosaic``
   (:func:`ingest.raster.job.ingest_raster`: staged COGs renamed when complete, one catalogue
   transaction, advisory lock per layer), so a killed run leaves no half-registered layer.
   With ``zones_dir`` the zone mosaics are kept, so even a run killed mid-drive keeps every
   zone finished so far, ready for ``ugvmap ingest raster``.
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import time
from collections import Counter, deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from sqlalchemy.orm import Session
from tqdm import tqdm

from app.db.models import SLUG_RE
from ingest.ipm import IpmInputError
from ingest.ipm.calibration import Calibration, load_calibration
from ingest.ipm.frames import UNREADABLE, FrameError, FrameRef, FrameSet, open_frames
from ingest.ipm.grid import GridPose, ZoneGrid
from ingest.ipm.lookup import IpmLookup, build_lookup, sample_patch
from ingest.ipm.place import PlacedPatch, place
from ingest.ipm.poses import NO_POSE, Pose, PoseTrack, interpolate_poses, read_poses
from ingest.ipm.qrpose import CORNERS, read_pose
from ingest.ipm.stitch import BLENDS, ZoneStitcher
from ingest.ipm.trajectory import store_trajectory, trajectory_line
from ingest.raster.job import ingest_raster
from ingest.raster.sources import SourceError

WRONG_SIZE, NO_QR, NO_GROUND = "wrong image size", "no readable QR pose", "no ground in view"
#: Share of the job's progress spent on frames; the rest is the raster ingest (COGs).
FRAMES_SHARE = 0.8
#: A zone is written once the vehicle is this many windows away from it.
REACH_WINDOWS = 1.0

PoseLookup = Callable[[PoseTrack, np.ndarray, float], list[Pose | str]]


@dataclass(frozen=True)
class IpmOptions:
    """Everything ``ugvmap ingest ipm`` lets the user choose, with the CLI's defaults, so the
    API, the CLI and the benchmark run the same job; checked by :func:`ingest_ipm` before
    anything is read."""

    resolution_m: float = 0.06
    window_m: float = 30.0
    range_m: float | None = None
    """Farthest ground distance from the camera that is written; default half the window."""
    frames: slice = field(default_factory=lambda: slice(None))
    workers: int = field(default_factory=lambda: os.cpu_count() or 1)
    blend: str = "nearest"
    zone_size_px: tuple[int, int] = (2048, 2048)
    overlap_px: tuple[int, int] = (128, 128)
    max_gap_s: float = 0.5
    origin: tuple[float, float] | None = None
    """(lon, lat) of the zone grid's origin; default: zone (0, 0) centred on the first pose."""
    qr_corner: str | None = None
    title: str | None = None
    priority: int = 0
    replace: bool = False
    """Zones already in the layer (the same drive again) replace their sources (else the
    ingest is refused, as ``ugvmap ingest raster`` refuses a file already in the layer)."""


@dataclass
class IpmSummary:
    """What a finished ingest did, for the CLI's report and the benchmark: how many frames
    were used or skipped (and why), what was covered and written, memory and time."""

    layer: str
    version: int
    frames: int
    used: int
    skipped: Counter
    examples: dict[str, str]
    area_m2: float
    zones_written: int
    zones_dropped: int
    origin: tuple[float, float]
    crs: str
    peak_buffer_bytes: int
    peak_open_zones: int
    frames_seconds: float
    total_seconds: float

    def lines(self) -> list[str]:
        """The report the CLI prints: skip reasons with one example each, so a user sees why
        frames were dropped without reading a log."""
        skipped = sum(self.skipped.values())
        why = ", ".join(f"{n} {reason}" for reason, n in self.skipped.most_common())
        out = [f"frames: {self.used} used, {skipped} skipped" + (f" ({why})" if why else "")
               + f" of {self.frames}"]
        out += [f"  e.g. {reason}: {msg}" for reason, msg in self.examples.items()]
        out.append(f"area covered: {self.area_m2:,.0f} m² ({self.area_m2 / 1e4:.2f} ha)")
        out.append(f"zones written: {self.zones_written}"
                   + (f" ({self.zones_dropped} slivers dropped)" if self.zones_dropped else "")
                   + f", grid origin lon {self.origin[0]:.7f} lat {self.origin[1]:.7f} "
                     f"in {self.crs}; at most {self.peak_open_zones} open at once "
                     f"({self.peak_buffer_bytes / 2**20:.0f} MiB of buffers)")
        rate = self.used / self.frames_seconds if self.frames_seconds else 0.0
        out.append(f"time: {self.frames_seconds:.1f} s for frames ({rate:.1f} frames/s), "
                   f"{self.total_seconds:.1f} s in all")
        out.append(f"layer {self.layer} at version {self.version}")
        return out


@dataclass(frozen=True)
class _Outcome:
    placed: PlacedPatch | None = None
    pose: GridPose | None = None
    where: Pose | None = None
    """The pose (lon/lat) the frame was placed with: a point of the drive's trajectory."""
    skip: str | None = None
    message: str = ""


@dataclass(frozen=True)
class _Context:
    calib: Calibration
    lookup: IpmLookup
    grid: ZoneGrid
    qr_corner: str | None


def _process(ref: FrameRef, pose: Pose | None, ctx: _Context) -> _Outcome:
    """Everything one frame needs, run in a worker thread."""
    try:
        image = ref.load()
    except FrameError as exc:
        return _Outcome(skip=UNREADABLE, message=str(exc))
    width, height = ctx.calib.image_size
    if image.shape[:2] != (height, width):
        return _Outcome(skip=WRONG_SIZE,
                        message=f"{ref.name} is {image.shape[1]}x{image.shape[0]} px but the "
                                f"calibration's image_size is {width}x{height}")
    if ctx.qr_corner:
        pose = read_pose(image, ctx.qr_corner)
        if pose is None:
            return _Outcome(skip=NO_QR,
                            message=f"{ref.name}: no pose QR code in the {ctx.qr_corner} corner")
    assert pose is not None
    grid_pose = ctx.grid.to_grid([pose.lon], [pose.lat], [pose.heading_deg])[0]
    placed = place(sample_patch(image, ctx.lookup), ctx.lookup.window, grid_pose,
                   ctx.grid.resolution_m)
    if placed is None:
        return _Outcome(skip=NO_GROUND, message=f"{ref.name}: nothing valid")
    return _Outcome(placed, grid_pose, pose)


def _first_qr_pose(frames: FrameSet, corner: str, limit: int = 200) -> Pose:
    """The first pose stamped in the drive (it anchors the zone grid in QR mode)."""
    for n, ref in enumerate(frames):
        if n >= limit:
            break
        try:
            pose = read_pose(ref.load(), corner)
        except FrameError:
            continue
        if pose is not None:
            return pose
    raise IpmInputError(f"no pose QR code found in the {corner} corner of the first "
                        f"{min(limit, frames.count)} frames")


def _check_options(layer: str, options: IpmOptions, poses: Path | None) -> None:
    if not re.match(SLUG_RE, layer):
        raise IpmInputError(f"layer slug {layer!r} must match {SLUG_RE}")
    if options.blend not in BLENDS:
        raise IpmInputError(f"--blend must be one of {', '.join(BLENDS)}")
    if options.qr_corner is not None and options.qr_corner not in CORNERS:
        raise IpmInputError(f"--qr-pose must be one of {', '.join(CORNERS)}")
    if (poses is None) == (options.qr_corner is None):
        raise IpmInputError("give the poses either with --poses poses.csv or from QR codes "
                            "in the frames with --qr-pose CORNER (exactly one of them)")
    if not 0.001 <= options.resolution_m <= 100:
        raise IpmInputError(f"--resolution {options.resolution_m} m/px is not plausible")
    if options.window_m <= 0:
        raise IpmInputError("--window must be positive")
    if options.workers < 1:
        raise IpmInputError("--workers must be at least 1")
    if options.max_gap_s <= 0:
        raise IpmInputError("--max-pose-gap must be positive")


@dataclass
class DriveResult:
    """What :func:`stitch_drive` did: the stitcher (written zones, stats) and the frames."""

    stitcher: ZoneStitcher
    used: int = 0
    skipped: Counter = field(default_factory=Counter)
    examples: dict[str, str] = field(default_factory=dict)
    """One message per skip reason."""
    times: list[float] = field(default_factory=list)
    """Times of the frames, for the "no pose" hint."""
    poses: list[Pose] = field(default_factory=list)
    """Poses of the frames used: the trajectory stored with the layer."""

    def no_frame_used(self, track: PoseTrack | None) -> str:
        """The one-line error when every frame was skipped; when frames fell outside the pose
        stream it shows both time ranges, since different clocks are the usual cause."""
        why = ", ".join(f"{n} {reason}" for reason, n in self.skipped.most_common())
        times = [t for t in self.times if np.isfinite(t)]
        hint = ""
        if track is not None and self.skipped.get(NO_POSE) and times:
            hint = (f" (frame times {min(times):.3f}..{max(times):.3f} s, poses "
                    f"{track.t[0]:.3f}..{track.t[-1]:.3f} s: same clock?)")
        return f"no frame could be used: {why}{hint}"


def stitch_drive(frames: FrameSet, track: PoseTrack | None, ctx: _Context,
                 options: IpmOptions, out_dir: Path, pose_lookup: PoseLookup,
                 progress: Callable[[float, str], None]) -> DriveResult:
    """Run every frame through IPM into zone mosaics in ``out_dir``."""
    reach = REACH_WINDOWS * options.window_m / options.resolution_m
    result = DriveResult(ZoneStitcher(ctx.grid, options.blend, out_dir, reach))
    stitcher = result.stitcher
    bar = tqdm(total=frames.count, desc="ipm frames", unit="frame",
               disable=not sys.stderr.isatty())
    last_report = 0.0

    def consume(outcome: _Outcome) -> None:
        nonlocal last_report
        bar.update(1)
        if outcome.skip:
            if outcome.skip == WRONG_SIZE and result.used == 0:
                # The first frames decide: a calibration for another camera is an input error.
                raise IpmInputError(outcome.message)
            result.skipped[outcome.skip] += 1
            result.examples.setdefault(outcome.skip, outcome.message)
        else:
            assert outcome.placed is not None and outcome.pose is not None
            assert outcome.where is not None
            stitcher.add(outcome.placed)
            result.poses.append(outcome.where)
            stitcher.close_far(outcome.pose.col, outcome.pose.row)
            result.used += 1
        now = time.monotonic()
        if now - last_report > 0.5:
            last_report = now
            progress(FRAMES_SHARE * bar.n / max(frames.count, 1),
                     f"frame {bar.n}/{frames.count}, {stitcher.stats.zones_written} zones")

    pool = ThreadPoolExecutor(options.workers, thread_name_prefix="ipm")
    pending: deque[Future | _Outcome] = deque()
    try:
        for ref in frames:
            result.times.append(ref.t)
            if track is None:
                pending.append(pool.submit(_process, ref, None, ctx))
            else:
                pose = pose_lookup(track, np.array([ref.t]), options.max_gap_s)[0]
                pending.append(_Outcome(skip=pose, message=f"{ref.name} at "
                                        f"t={ref.t}") if isinstance(pose, str)
                               else pool.submit(_process, ref, pose, ctx))
            while len(pending) > 2 * options.workers:
                item = pending.popleft()
                consume(item.result() if isinstance(item, Future) else item)
        while pending:
            item = pending.popleft()
            consume(item.result() if isinstance(item, Future) else item)
        stitcher.close_all()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        bar.close()
    return result


def drive_name(frames_path: Path, frames: slice) -> str:
    """What names a drive in ``layer_trajectories``: its frames (absolute), and the part of
    them used when ``--frames`` chose one, so the same drive ingested again replaces its row."""
    start, stop = ("" if v is None else v for v in (frames.start, frames.stop))
    part = "" if frames == slice(None) else f"[{start}:{stop}]"
    return f"{Path(frames_path).resolve()}{part}"


def ingest_ipm(frames_path: Path, layer: str, calib_path: Path, poses_path: Path | None = None,
               frame_times: Path | None = None, options: IpmOptions | None = None, *,
               zones_dir: Path | None = None, pose_lookup: PoseLookup = interpolate_poses,
               database_url: str | None = None, store: Path | None = None,
               on_progress: Callable[[float, str], None] | None = None) -> IpmSummary:
    """Ingest a drive into layer ``layer`` (kind ``ipm-mosaic``); raise
    :class:`IpmInputError` on bad input. ``pose_lookup`` is how a frame time becomes a pose
    (linear interpolation; tests swap in nearest-sample to show it matters)."""
    started = time.monotonic()
    options = options or IpmOptions()
    _check_options(layer, options, poses_path)
    calib = load_calibration(calib_path)
    frames = open_frames(Path(frames_path), frame_times, options.frames,
                         need_times=options.qr_corner is None)
    if frames.count == 0:
        raise IpmInputError(f"{frames_path}: no frames selected")
    track = read_poses(poses_path) if poses_path is not None else None
    range_m = options.range_m if options.range_m is not None else options.window_m / 2
    lookup = build_lookup(calib, options.window_m, options.resolution_m, range_m)
    if options.origin is not None:
        grid = ZoneGrid(*options.origin, options.resolution_m, options.zone_size_px,
                        options.overlap_px)
    else:
        if track is not None:
            first = Pose(float(track.t[0]), float(track.lon[0]), float(track.lat[0]), 0.0)
        else:
            first = _first_qr_pose(frames, str(options.qr_corner))
        grid = ZoneGrid.centred_on(first.lon, first.lat, options.resolution_m,
                                   options.zone_size_px, options.overlap_px)
    grid.check()
    if zones_dir is not None and any(Path(zones_dir).glob("zone_*.tif")):
        raise IpmInputError(f"--zones-dir {zones_dir} already holds zone mosaics; give an "
                            "empty or new directory")
    progress = on_progress or (lambda fraction, message: None)
    ctx = _Context(calib, lookup, grid, options.qr_corner)
    with tempfile.TemporaryDirectory(prefix="ugvmap-ipm-") as tmp:
        out_dir = Path(zones_dir) if zones_dir is not None else Path(tmp)
        drive = stitch_drive(frames, track, ctx, options, out_dir, pose_lookup, progress)
        stitcher = drive.stitcher
        frames_seconds = time.monotonic() - started
        if drive.used == 0:
            raise IpmInputError(drive.no_frame_used(track))
        if not stitcher.written:
            raise IpmInputError("the frames saw too little ground to write any zone")
        line = trajectory_line(drive.poses)

        def keep_trajectory(session: Session) -> None:
            if line is not None:
                store_trajectory(session, layer, drive_name(frames_path, options.frames), line,
                                 {"frames": drive.used, "t0": drive.poses[0].t,
                                  "t1": drive.poses[-1].t,
                                  "poses": str(poses_path) if poses_path else "qr"})

        try:
            report = ingest_raster(
                stitcher.written, layer, title=options.title, kind="ipm-mosaic",
                priority=options.priority, database_url=database_url, store=store,
                replace=options.replace, add=True,  # a drive's zones: wherever it drove
                on_progress=lambda f, step: progress(FRAMES_SHARE + (1 - FRAMES_SHARE) * f,
                                                     f"zone COG {step}"),
                after_register=keep_trajectory)
        except SourceError as exc:
            raise IpmInputError(str(exc)) from exc
    stats = stitcher.stats
    return IpmSummary(
        layer=layer, version=report.version, frames=frames.count, used=drive.used,
        skipped=drive.skipped, examples=drive.examples,
        area_m2=stats.covered_px * options.resolution_m ** 2,
        zones_written=stats.zones_written, zones_dropped=stats.zones_dropped,
        origin=(grid.origin_lon, grid.origin_lat),
        crs=grid.sidecar(0, 0).crs().to_string(), peak_buffer_bytes=stats.peak_bytes,
        peak_open_zones=stats.peak_open_zones, frames_seconds=frames_seconds,
        total_seconds=time.monotonic() - started)
