"""One frame's ground patch onto the zone grid: rotate by the heading, place by position.

The patch (vehicle frame, forward up) goes to global grid pixels through one affine map
(patch -> vehicle metres -> grid pixels), applied with ``cv2.warpAffine``. Only pixels whose
four bilinear neighbours are all valid stay valid, so edges never fade into the invalid
(black) surround. The squared distance to the camera is kept per pixel for blending.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ingest.ipm.grid import GridPose
from ingest.ipm.lookup import GroundWindow


@dataclass(frozen=True)
class PlacedPatch:
    """A frame's contribution: arrays whose top-left pixel is global pixel (col0, row0)."""

    col0: int
    row0: int
    colour: np.ndarray
    """(h, w, 3) uint8, channel order as read (BGR)."""
    valid: np.ndarray
    """(h, w) bool."""
    dist2: np.ndarray
    """(h, w) float32: squared horizontal distance from the camera, in grid pixels²."""

    @property
    def shape(self) -> tuple[int, int]:
        """(h, w) in grid pixels: with (col0, row0), the box of the grid the patch touches."""
        return self.valid.shape


def vehicle_to_grid(pose: GridPose, resolution_m: float) -> np.ndarray:
    """3x3 affine: vehicle (x right, y forward; metres) -> continuous global grid pixel."""
    f = pose.scale / resolution_m
    c, s = math.cos(pose.bearing), math.sin(pose.bearing)
    # east = x cos b + y sin b, north = -x sin b + y cos b; rows grow south.
    return np.array([[f * c, f * s, pose.col],
                     [f * s, -f * c, pose.row],
                     [0.0, 0.0, 1.0]])


def place(patch: np.ndarray, window: GroundWindow, pose: GridPose,
          resolution_m: float) -> PlacedPatch | None:
    """Warp ``patch`` ((n, n, 4): colour + validity) onto the grid; None if nothing valid."""
    to_grid = vehicle_to_grid(pose, resolution_m)
    affine = to_grid @ window.to_vehicle()
    n = window.size_px
    corners = affine @ np.array([[0, n, 0, n], [0, 0, n, n], [1, 1, 1, 1]], float)
    col0, row0 = (math.floor(v) for v in corners[:2].min(axis=1))
    col1, row1 = (math.ceil(v) for v in corners[:2].max(axis=1))
    # OpenCV puts pixel centres on integers: shift in by half a pixel, out by half + origin.
    linear, offset = affine[:2, :2], affine[:2, 2]
    shift = linear @ [0.5, 0.5] + offset - 0.5 - [col0, row0]
    warped = cv2.warpAffine(patch, np.hstack([linear, shift[:, None]]),
                            (col1 - col0, row1 - row0), flags=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    valid = warped[..., 3] == 255
    if not valid.any():
        return None
    cam_col, cam_row, _ = to_grid @ [*window.centre_xy, 1.0]
    dc = (np.arange(col0, col1, dtype=np.float32) + 0.5 - np.float32(cam_col)) ** 2
    dr = (np.arange(row0, row1, dtype=np.float32) + 0.5 - np.float32(cam_row)) ** 2
    return PlacedPatch(col0, row0, warped[..., :3], valid, dr[:, None] + dc[None, :])
