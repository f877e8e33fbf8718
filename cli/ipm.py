"""``ugvmap ingest ipm``: a drive's panoramas + poses -> an ipm-mosaic layer.

Registered on the ``ingest`` group of ``cli.main``. Heavy imports happen inside the command so
``ugvmap --help`` stays instant; input problems are one line (:class:`app.errors.UserError`).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import click

T = TypeVar("T")


def _slice(ctx: click.Context, param: click.Parameter, value: str | None) -> slice:
    if not value:
        return slice(None)
    parts = value.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        start, stop = (int(p) if p.strip() else None for p in parts)
    except ValueError:
        raise click.BadParameter(f"{value!r} is not a:b (frame numbers from 0, b excluded; "
                                 "either may be empty)") from None
    if (start is not None and start < 0) or (stop is not None and stop < 0):
        raise click.BadParameter(f"{value!r}: frame numbers are >= 0")
    return slice(start, stop)


def _pair(kind: Callable[[str], T], sep: str
          ) -> Callable[[click.Context, click.Parameter, str | None], tuple[T, T] | None]:
    """A click callback parsing "a<sep>b" into two ``kind`` values (None stays None)."""
    def parse(ctx: click.Context, param: click.Parameter, value: str | None
              ) -> tuple[T, T] | None:
        if value is None:
            return None
        try:
            a, b = (kind(v) for v in value.lower().split(sep))
        except ValueError:
            raise click.BadParameter(f"{value!r} is not two numbers separated by "
                                     f"{sep!r}") from None
        return a, b
    return parse


@click.command("ipm")
@click.argument("frames", type=click.Path(path_type=Path))
@click.option("--poses", type=click.Path(path_type=Path, dir_okay=False, exists=True),
              help="CSV t,lon,lat,heading_deg (heading clockwise from true north).")
@click.option("--qr-pose", "qr_corner",
              type=click.Choice(["top-left", "top-right", "bottom-left", "bottom-right"]),
              help="Read each frame's pose from the QR code stamped in this corner instead.")
@click.option("--calib", required=True,
              type=click.Path(path_type=Path, dir_okay=False, exists=True),
              help="Calibration JSON (image_size, camera_position_m, rotation or "
                   "pitch/roll/yaw_deg, vehicle_mask).")
@click.option("--layer", "slug", required=True, help="Layer slug (created if new).")
@click.option("--frame-times", type=click.Path(path_type=Path, dir_okay=False, exists=True),
              help="For a video: CSV with a t column, one row per frame.")
@click.option("--resolution", default=0.06, show_default=True, type=float,
              help="Ground resolution of the mosaic, metres per pixel.")
@click.option("--frames", "selection", callback=_slice, help="Only frames a:b (from 0).")
@click.option("--window", default=30.0, show_default=True, type=float,
              help="Side of the square ground window sampled around the camera, metres.")
@click.option("--range", "range_m", type=float,
              help="Farthest ground distance from the camera written, metres "
                   "[default: half the window].")
@click.option("--workers", default=os.cpu_count() or 1, show_default=True, type=int,
              help="Threads decoding and projecting frames.")
@click.option("--blend", default="nearest", show_default=True,
              type=click.Choice(["nearest", "later", "weighted"]),
              help="nearest: each pixel from the frame that saw it closest; later: later "
                   "frames over earlier; weighted: 1/d² average.")
@click.option("--zone-size", default="2048x2048", show_default=True, callback=_pair(int, "x"),
              help="Zone mosaic size WxH, pixels.")
@click.option("--zone-overlap", default="128x128", show_default=True,
              callback=_pair(int, "x"), help="Overlap of neighbouring zones WxH, pixels.")
@click.option("--origin", callback=_pair(float, ","),
              help="LON,LAT of the zone grid's origin (north-west corner of zone 0/0) "
                   "[default: zone 0/0 centred on the first pose].")
@click.option("--max-pose-gap", default=0.5, show_default=True, type=float,
              help="Skip frames between two poses farther apart than this, seconds.")
@click.option("--zones-dir", type=click.Path(path_type=Path, file_okay=False),
              help="Keep the zone mosaics (GeoTIFF + .zone.json) here.")
@click.option("--title", help="Human title of the layer.")
@click.option("--priority", default=0, show_default=True, type=int,
              help="Higher priority sources are drawn over lower ones; ties: newest on top.")
@click.option("--replace", is_flag=True,
              help="Zones already in the layer (the same drive again) replace their sources "
                   "(without it such a re-ingest is refused).")
def ingest_ipm_cmd(frames: Path, poses: Path | None, qr_corner: str | None, calib: Path,
                   slug: str, frame_times: Path | None, resolution: float, selection: slice,
                   window: float, range_m: float | None, workers: int, blend: str,
                   zone_size: tuple[int, int], zone_overlap: tuple[int, int],
                   origin: tuple[float, float] | None, max_pose_gap: float,
                   zones_dir: Path | None, title: str | None, priority: int,
                   replace: bool) -> None:
    """Stitch FRAMES (a directory with frames.csv, or a video) into layer SLUG.

    Each equirectangular frame is projected onto the ground plane (inverse perspective
    mapping), placed by its pose (interpolated from --poses, or read from a QR code) and
    stitched into the survey's zone grid; the zones become the sources of an ipm-mosaic
    layer, registered atomically like ``ugvmap ingest raster``.
    """
    from app.jobs.recorder import JobRecorder
    from ingest.ipm.job import IpmOptions, ingest_ipm

    options = IpmOptions(resolution_m=resolution, window_m=window, range_m=range_m,
                         frames=selection, workers=workers, blend=blend,
                         zone_size_px=zone_size, overlap_px=zone_overlap,
                         max_gap_s=max_pose_gap, origin=origin, qr_corner=qr_corner,
                         title=title, priority=priority, replace=replace)
    params = {"frames": str(frames), "poses": str(poses) if poses else None,
              "calib": str(calib), "frame_times": str(frame_times) if frame_times else None,
              "qr_pose": qr_corner, "resolution": resolution, "window": window,
              "range": range_m, "frames_selection": [selection.start, selection.stop],
              "blend": blend, "zone_size": zone_size, "zone_overlap": zone_overlap,
              "origin": origin, "max_pose_gap": max_pose_gap}
    with JobRecorder("ingest-ipm", slug, params) as job:
        summary = ingest_ipm(frames, slug, calib, poses, frame_times, options,
                             zones_dir=zones_dir, on_progress=job.progress)
    for line in summary.lines():
        click.echo(line)
