"""The GNSS/INS pose stream, and each frame's pose interpolated from it.

``poses.csv`` has a header with at least ``t,lon,lat,heading_deg`` (seconds on the frame
clock, WGS84 degrees, heading clockwise from true north); other columns (``alt``,
``pitch_deg``, ...) are allowed and ignored: the ground is taken as the plane the vehicle
stands on. Times must strictly increase: a stream that jumps back is refused (it would make
interpolation pick the wrong pair), never silently sorted.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ingest.ipm import IpmInputError

COLUMNS = ("t", "lon", "lat", "heading_deg")
#: Skip reasons, as counted in the summary.
NO_TIME, NO_POSE, POSE_GAP = "no frame time", "outside the pose stream", "in a pose gap"


@dataclass(frozen=True)
class Pose:
    """Where one frame was taken: ``t`` on the frame clock, WGS84 degrees, heading clockwise
    from *true* north (the grid turns it to grid north per pose)."""

    t: float
    lon: float
    lat: float
    heading_deg: float


@dataclass(frozen=True)
class PoseTrack:
    """The validated stream as parallel arrays (``t`` strictly increasing), ready for
    vectorised interpolation."""

    t: np.ndarray
    lon: np.ndarray
    lat: np.ndarray
    heading_deg: np.ndarray


def read_poses(path: Path) -> PoseTrack:
    """Read and validate a pose stream; raise :class:`IpmInputError` with the bad line."""
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
            if missing:
                raise IpmInputError(f"{path}: missing column(s) {', '.join(missing)} "
                                    f"(header must include {','.join(COLUMNS)})")
            rows: list[list[float]] = []
            for row in reader:
                try:
                    values = [float(row[c]) for c in COLUMNS]
                except (TypeError, ValueError):
                    raise IpmInputError(f"{path} line {reader.line_num}: "
                                        f"{[row[c] for c in COLUMNS]} are not all numbers"
                                        ) from None
                if not all(map(math.isfinite, values)):
                    raise IpmInputError(f"{path} line {reader.line_num}: non-finite value")
                t, lon, lat, _ = values
                if not (-180 <= lon <= 180 and -90 <= lat <= 90):
                    raise IpmInputError(f"{path} line {reader.line_num}: lon/lat {lon}, {lat} "
                                        "are not WGS84 degrees")
                if rows and t <= rows[-1][0]:
                    raise IpmInputError(f"{path} line {reader.line_num}: time {t} is not after "
                                        f"the previous {rows[-1][0]} (pose times must "
                                        "strictly increase)")
                rows.append(values)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise IpmInputError(f"{path}: cannot read the poses ({exc})") from exc
    if len(rows) < 2:
        raise IpmInputError(f"{path}: at least two poses are needed, found {len(rows)}")
    t, lon, lat, heading = np.array(rows).T
    return PoseTrack(t, lon, lat, heading)


def interpolate_poses(track: PoseTrack, times: np.ndarray,
                      max_gap_s: float) -> list[Pose | str]:
    """Each frame time's pose, or why it has none.

    Position is linear in time between the two surrounding samples; heading is linear on
    the circle (the short way round). Frames before the first or after the last sample, or
    between two samples more than ``max_gap_s`` apart (unless exactly at one of them), get a
    skip reason instead.
    """
    times = np.asarray(times, float)
    after = np.searchsorted(track.t, times, side="right").clip(1, len(track.t) - 1)
    before = after - 1
    gap = track.t[after] - track.t[before]
    w = (times - track.t[before]) / gap
    heading = np.degrees(np.unwrap(np.radians(track.heading_deg)))
    lon = track.lon[before] + w * (track.lon[after] - track.lon[before])
    lat = track.lat[before] + w * (track.lat[after] - track.lat[before])
    hdg = (heading[before] + w * (heading[after] - heading[before])) % 360
    out: list[Pose | str] = []
    for i, t in enumerate(times):
        if not math.isfinite(t):
            out.append(NO_TIME)
        elif t < track.t[0] or t > track.t[-1]:
            out.append(NO_POSE)
        elif gap[i] > max_gap_s and t not in (track.t[before[i]], track.t[after[i]]):
            out.append(POSE_GAP)
        else:
            out.append(Pose(float(t), float(lon[i]), float(lat[i]), float(hdg[i])))
    return out
