"""The equirectangular panorama model (the issue's contract, in one place).

A camera-frame direction d = (x, y, z) (x right, y forward, z up) has azimuth
φ = atan2(x, y) (0 = forward, +90° = right) and polar angle θ = arccos(z / |d|)
(0 = straight up). Its pixel is u = (φ / 2π + 0.5) · W, v = θ / π · H in continuous image
coordinates, where pixel (i, j) spans [i, i+1) x [j, j+1) so its centre is at +0.5.
OpenCV samples with pixel centres on integers, hence :func:`to_cv`.
"""

from __future__ import annotations

import numpy as np


def direction_to_pixel(d: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Continuous pixel (u, v) of camera-frame directions ``d`` (..., 3); need not be unit."""
    width, height = size
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    phi = np.arctan2(x, y)
    theta = np.arctan2(np.hypot(x, y), z)  # = arccos(z/|d|), but exact near the poles
    return (phi / (2 * np.pi) + 0.5) * width, theta / np.pi * height


def pixel_to_direction(u: np.ndarray, v: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Unit camera-frame direction (..., 3) seen at continuous pixel (u, v)."""
    width, height = size
    phi = (np.asarray(u, float) / width - 0.5) * 2 * np.pi
    theta = np.asarray(v, float) / height * np.pi
    return np.stack([np.sin(theta) * np.sin(phi), np.sin(theta) * np.cos(phi),
                     np.cos(theta)], axis=-1)


def to_cv(coord: np.ndarray) -> np.ndarray:
    """Continuous pixel coordinate -> OpenCV's (centres on integers), as float32 for remap."""
    return (np.asarray(coord) - 0.5).astype(np.float32)
