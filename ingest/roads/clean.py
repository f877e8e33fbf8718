"""Morphological cleaning of the road mask, with every size in metres.

Opening removes specks and hairlines narrower than a road; closing bridges small gaps (cars,
shadows, lane markings); small components are noise and small holes are cars or trees
standing on the road. Sizes are metres so the same defaults work at 0.16 m and 1 m per pixel.
"""

from __future__ import annotations

import cv2
import numpy as np


def disk(diameter_px: int) -> np.ndarray:
    """Elliptical structuring element ``diameter_px`` across."""
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (diameter_px, diameter_px))


def metres_to_px(metres: float, resolution_m: float) -> int:
    """Odd kernel diameter in pixels for a size in metres (0 or 1 means "skip")."""
    px = round(metres / resolution_m)
    return px + 1 if px > 1 and px % 2 == 0 else px


def remove_small_components(mask: np.ndarray, min_area_px: int,
                            connectivity: int = 8) -> np.ndarray:
    """Drop connected components smaller than ``min_area_px``."""
    if min_area_px <= 1 or not mask.any():
        return mask
    _, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8),
                                                        connectivity=connectivity)
    keep = stats[:, cv2.CC_STAT_AREA] >= min_area_px
    keep[0] = False
    return keep[lab]


def fill_small_holes(mask: np.ndarray, max_hole_px: int) -> np.ndarray:
    """Fill background components smaller than ``max_hole_px`` (4-connected: the dual of the
    8-connected foreground)."""
    return mask | (~mask & ~remove_small_components(~mask, max_hole_px, connectivity=4))


def clean_mask(mask: np.ndarray, resolution_m: float, open_m: float = 1.0,
               close_m: float = 2.0, min_area_m2: float = 150.0,
               max_hole_m2: float = 40.0) -> np.ndarray:
    """Open, close, drop small components, fill small holes; all sizes in metres."""
    out: np.ndarray = mask.astype(np.uint8)
    k_open = metres_to_px(open_m, resolution_m)
    if k_open > 1:
        out = cv2.morphologyEx(out, cv2.MORPH_OPEN, disk(k_open))
    k_close = metres_to_px(close_m, resolution_m)
    if k_close > 1:
        out = cv2.morphologyEx(out, cv2.MORPH_CLOSE, disk(k_close))
    px_area = resolution_m * resolution_m
    out = remove_small_components(out.astype(bool), round(min_area_m2 / px_area))
    return fill_small_holes(out, round(max_hole_m2 / px_area))
