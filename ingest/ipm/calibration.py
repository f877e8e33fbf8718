"""Where the panoramic camera sits on the vehicle, and how ground points map to its pixels.

Vehicle frame: x right, y forward, z up, origin at the pose point on the ground. The
calibration file (JSON)::

    {"image_size": [W, H],                 # equirectangular: W = 2 H
     "camera_position_m": [x, y, z],       # camera centre in the vehicle frame, z > 0
     "rotation": [[...], [...], [...]],    # d_cam = R · d_vehicle
     "vehicle_mask": "mask.png"}           # optional, relative to this file; 255 = car body

``pitch_deg``/``roll_deg``/``yaw_deg`` may replace ``rotation`` (see
:func:`rotation_from_angles` for the order). Everything is validated on load so a bad file is
one clear line before any frame is read.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ingest.ipm import IpmInputError
from ingest.ipm.panorama import direction_to_pixel, pixel_to_direction

#: A camera higher than this above the ground is a unit or sign mistake, not a vehicle.
MAX_CAMERA_HEIGHT_M = 50.0
ANGLE_KEYS = ("pitch_deg", "roll_deg", "yaw_deg")


@dataclass(frozen=True)
class Calibration:
    """A validated calibration: everything the ground -> pixel mapping needs, fixed for the
    whole drive (which is what lets :mod:`ingest.ipm.lookup` compute it once)."""

    image_size: tuple[int, int]
    camera_position_m: np.ndarray
    rotation: np.ndarray
    """d_cam = rotation @ d_vehicle."""
    vehicle_mask: np.ndarray | None = None
    """(H, W) bool, True where the car body hides the ground."""


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def rotation_from_angles(pitch_deg: float = 0.0, roll_deg: float = 0.0,
                         yaw_deg: float = 0.0) -> np.ndarray:
    """R (d_cam = R · d_vehicle) of a camera mounted with the given angles.

    The camera starts aligned with the vehicle and is turned, each turn about the camera's
    own (already turned) axes: first **yaw** about z (positive = clockwise seen from above,
    like a heading: the camera's forward swings to the vehicle's right), then **pitch** about
    x (positive = forward axis up), then **roll** about y (positive = right side down). The
    camera's axes in the vehicle frame are the columns of M = Rz(−yaw) · Rx(pitch) · Ry(roll),
    so d_vehicle = M · d_cam and R = Mᵀ.
    """
    m = (_rz(-math.radians(yaw_deg)) @ _rx(math.radians(pitch_deg))
         @ _ry(math.radians(roll_deg)))
    return m.T


def _numbers(doc: dict, key: str, count: int, source: Path) -> list[float]:
    value = doc.get(key)
    try:
        numbers = [] if value is None else [float(v) for v in value]
    except (TypeError, ValueError):
        numbers = []
    if len(numbers) != count or not all(map(math.isfinite, numbers)):
        raise IpmInputError(f"{source}: {key} must be {count} numbers, not {value!r}")
    return numbers


def _rotation(doc: dict, source: Path) -> np.ndarray:
    angles = [k for k in ANGLE_KEYS if k in doc]
    if "rotation" in doc and angles:
        raise IpmInputError(f"{source}: give either rotation or {'/'.join(ANGLE_KEYS)}, "
                            "not both")
    if angles:
        try:
            values = {k: float(doc[k]) for k in angles}
        except (TypeError, ValueError):
            raise IpmInputError(f"{source}: {'/'.join(angles)} must be numbers") from None
        if not all(map(math.isfinite, values.values())):
            raise IpmInputError(f"{source}: {'/'.join(angles)} must be finite")
        return rotation_from_angles(**values)
    if "rotation" not in doc:
        raise IpmInputError(f"{source}: no rotation (a 3x3 matrix, d_cam = R · d_vehicle) "
                            f"and no {'/'.join(ANGLE_KEYS)}")
    try:
        rot = np.array(doc["rotation"], dtype=float)
    except (TypeError, ValueError):
        rot = np.zeros(0)
    if rot.shape != (3, 3) or not np.isfinite(rot).all():
        raise IpmInputError(f"{source}: rotation must be a 3x3 matrix of numbers")
    if np.abs(rot @ rot.T - np.eye(3)).max() > 1e-3 or np.linalg.det(rot) < 0:
        raise IpmInputError(f"{source}: rotation is not a rotation matrix (orthonormal, "
                            "determinant +1)")
    return rot


def _mask(doc: dict, source: Path, size: tuple[int, int]) -> np.ndarray | None:
    name = doc.get("vehicle_mask")
    if not name:
        return None
    path = source.parent / str(name)
    mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) if path.is_file() else None
    if mask is None:
        raise IpmInputError(f"{source}: vehicle_mask {path} is missing or not an image")
    if (mask.shape[1], mask.shape[0]) != size:
        raise IpmInputError(f"{source}: vehicle_mask is {mask.shape[1]}x{mask.shape[0]} px "
                            f"but image_size is {size[0]}x{size[1]}")
    return mask >= 128


def load_calibration(path: Path) -> Calibration:
    """Read and validate a calibration file; raise :class:`IpmInputError` on any problem."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise IpmInputError(f"{path}: cannot read the calibration ({exc})") from exc
    if not isinstance(doc, dict):
        raise IpmInputError(f"{path}: the calibration must be a JSON object")
    width, height = _numbers(doc, "image_size", 2, path)
    if width != int(width) or height != int(height) or height < 2 or width != 2 * height:
        raise IpmInputError(f"{path}: image_size {doc['image_size']} is not an equirectangular "
                            "panorama size (integers, width = 2 x height)")
    size = (int(width), int(height))
    position = np.array(_numbers(doc, "camera_position_m", 3, path))
    if position[2] <= 0:
        raise IpmInputError(f"{path}: camera_position_m puts the camera at z = {position[2]} m, "
                            "on or below the ground (z is the height above the ground, > 0)")
    if position[2] > MAX_CAMERA_HEIGHT_M:
        raise IpmInputError(f"{path}: camera height {position[2]} m is not plausible "
                            f"(> {MAX_CAMERA_HEIGHT_M} m; metres expected)")
    return Calibration(size, position, _rotation(doc, path), _mask(doc, path, size))


def ground_to_pixel(xy: np.ndarray, calib: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Continuous panorama pixel (u, v) that sees vehicle-frame ground points ``xy`` (..., 2)."""
    xy = np.asarray(xy, float)
    d = np.concatenate([xy - calib.camera_position_m[:2],
                        np.broadcast_to(-calib.camera_position_m[2], xy.shape[:-1])[..., None]],
                       axis=-1)
    return direction_to_pixel(d @ calib.rotation.T, calib.image_size)


def pixel_to_ground(u: np.ndarray, v: np.ndarray, calib: Calibration) -> np.ndarray:
    """Vehicle-frame ground point (..., 2) seen at panorama pixel (u, v); NaN at or above
    the horizon (the ray never meets the ground)."""
    d = pixel_to_direction(u, v, calib.image_size) @ calib.rotation  # = Rᵀ · d_cam
    down = d[..., 2] < 0
    t = np.where(down, -calib.camera_position_m[2] / np.where(down, d[..., 2], -1.0), np.nan)
    return calib.camera_position_m[:2] + t[..., None] * d[..., :2]
