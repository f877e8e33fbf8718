"""Where paint is: pixels brighter than their surroundings within a marking's width.

A white top-hat (the image minus its morphological opening with a disc wider than any
marking) keeps what is narrow and bright — lines, dashes, stop lines — and drops what is wide
(the asphalt, its slow shading, shadows as a whole). Brightness is each pixel's largest
channel, so yellow paint (bright red and green, little blue) stands out as strongly as white.
Hysteresis keeps a worn line whole: weak pixels count where they touch strong ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from skimage.filters import apply_hysteresis_threshold

from ingest.roads.clean import metres_to_px


@dataclass(frozen=True)
class PaintParams:
    """Thresholds in metres and in brightness steps of 0-255."""

    widest_m: float = 0.8
    """Widest marking (a stop line is 0.3-0.6 m): the opening disc's diameter."""
    low: float = 18.0
    """Top-hat contrast a pixel needs when it touches a strong one."""
    high: float = 40.0
    """Top-hat contrast that makes a pixel paint on its own."""


def brightness(rgb: np.ndarray) -> np.ndarray:
    """(rows, cols) uint8 largest channel of an RGB image in [0, 1] (float) or 0-255."""
    top = rgb.max(axis=2) if rgb.ndim == 3 else rgb
    if top.dtype != np.uint8:
        top = np.clip(top * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return top


def top_hat(grey: np.ndarray, resolution_m: float, valid: np.ndarray | None,
            params: PaintParams = PaintParams()) -> np.ndarray:
    """(rows, cols) float32 contrast of narrow bright things. Pixels outside ``valid`` count
    as bright for the opening (so the edge of the coverage is not a bright line) and as no
    paint in the result."""
    size = max(3, metres_to_px(params.widest_m, resolution_m))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))
    filled = grey if valid is None else np.where(valid, grey, 255).astype(np.uint8)
    hat = cv2.subtract(filled, cv2.morphologyEx(filled, cv2.MORPH_OPEN, disc))
    if valid is not None:
        hat[~valid] = 0
    return hat.astype(np.float32)


def paint_mask(hat: np.ndarray, params: PaintParams = PaintParams()) -> np.ndarray:
    """Bool mask of paint from the top-hat contrast (hysteresis between low and high)."""
    return apply_hysteresis_threshold(hat, params.low, params.high)



def road_surface(hsv: np.ndarray, saturation: float) -> np.ndarray:
    """(rows, cols) float32 1 where the ground looks like road surface (grey: saturation below
    ``saturation``; not shadow-dark), from HSV with S and V in [0, 1]."""
    return ((hsv[..., 1] < saturation) & (hsv[..., 2] > 0.15)).astype(np.float32)


def near_road(surface: np.ndarray, resolution_m: float, window_m: float = 2.5,
              share: float = 0.4) -> np.ndarray:
    """Bool mask of pixels with road surface on ``share`` of the square ``window_m`` around
    them: paint elsewhere (grass, tree crowns) is texture, and dropping it before tracing
    saves the time of tracing and chaining thousands of pieces that would be dropped anyway."""
    k = max(3, round(window_m / resolution_m))
    return cv2.blur(surface, (k, k)) >= share
