"""The ground window and its fixed ground -> panorama-pixel lookup.

The calibration is fixed for a drive and the ground is a plane, so the panorama pixel that
sees a given ground cell *in the vehicle frame* never changes: the whole inverse perspective
mapping is computed once (:func:`build_lookup`) and every frame costs one ``cv2.remap``
(:func:`sample_patch`); only the placement of the patch on the map depends on the pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ingest.ipm import IpmInputError
from ingest.ipm.calibration import Calibration, ground_to_pixel
from ingest.ipm.panorama import to_cv

#: Car-body pixels are grown by this many panorama pixels, so bilinear sampling next to the
#: mask never mixes body colour into the ground.
MASK_GROW_PX = 2


@dataclass(frozen=True)
class GroundWindow:
    """A square of ``size_px`` x ``size_px`` ground cells of ``resolution_m``, centred on the
    camera's ground point, in the vehicle frame; row 0 is the forward edge, column 0 the
    left edge (so the patch looks like a map of a north-facing vehicle)."""

    resolution_m: float
    size_px: int
    centre_xy: tuple[float, float]

    def to_vehicle(self) -> np.ndarray:
        """3x3 affine: continuous patch pixel (col, row) -> vehicle (x, y) in metres."""
        half = self.size_px * self.resolution_m / 2
        x0, y0 = self.centre_xy
        return np.array([[self.resolution_m, 0.0, x0 - half],
                         [0.0, -self.resolution_m, y0 + half],
                         [0.0, 0.0, 1.0]])

    def cell_centres(self) -> np.ndarray:
        """(n, n, 2) vehicle-frame (x, y) of every cell centre."""
        a = np.arange(self.size_px) + 0.5
        cols, rows = np.meshgrid(a, a)
        m = self.to_vehicle()
        return np.stack([m[0, 0] * cols + m[0, 2], m[1, 1] * rows + m[1, 2]], axis=-1)


@dataclass(frozen=True)
class IpmLookup:
    """The drive's whole inverse perspective mapping, computed once: per ground cell, the
    panorama pixel to sample and whether the cell is usable."""

    window: GroundWindow
    map1: np.ndarray
    map2: np.ndarray
    """``cv2.remap`` maps (fixed point: the fastest form OpenCV samples with)."""
    valid: np.ndarray
    """(n, n) uint8, 255 where the cell is within range and not hidden by the car body."""


def build_lookup(calib: Calibration, window_m: float, resolution_m: float,
                 range_m: float) -> IpmLookup:
    """The ground window's panorama pixels for this calibration (once per drive)."""
    size_px = round(window_m / resolution_m)
    if not 8 <= size_px <= 20_000:
        raise IpmInputError(f"--window {window_m} m at {resolution_m} m/px is {size_px} px: "
                            "out of range (8..20000)")
    if range_m <= 0:
        raise IpmInputError(f"--range must be positive, not {range_m}")
    cam = calib.camera_position_m
    window = GroundWindow(resolution_m, size_px, (float(cam[0]), float(cam[1])))
    xy = window.cell_centres()
    u, v = ground_to_pixel(xy, calib)
    map_x, map_y = to_cv(u), to_cv(v)
    width, height = calib.image_size
    # Straight down (the nadir row) bilinear sampling would wrap to the top row: never ground.
    valid = (np.hypot(xy[..., 0] - cam[0], xy[..., 1] - cam[1]) <= range_m) \
        & (map_y <= height - 1)
    if calib.vehicle_mask is not None:
        grown = cv2.dilate(calib.vehicle_mask.astype(np.uint8),
                           np.ones((2 * MASK_GROW_PX + 1,) * 2, np.uint8))
        cols = np.clip(np.rint(map_x).astype(int), 0, width - 1)
        rows = np.clip(np.rint(map_y).astype(int), 0, height - 1)
        valid &= grown[rows, cols] == 0
    map1, map2 = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
    return IpmLookup(window, map1, map2, np.where(valid, 255, 0).astype(np.uint8))


def sample_patch(pano: np.ndarray, lookup: IpmLookup) -> np.ndarray:
    """The frame's ground window: (n, n, 4) uint8, colour channels + validity (255/0)."""
    ground = cv2.remap(pano, lookup.map1, lookup.map2, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_WRAP)
    return np.dstack([ground, lookup.valid])
