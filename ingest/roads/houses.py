"""House-edge removal: drop isolated blobs that look like a rectangle rather than a road.

Roofs and yards often share the road's colour. A roof blob is compact and its outline
simplifies (Ramer–Douglas–Peucker) to a quadrilateral with near-right corners and a modest
aspect ratio, while a road blob is long and branched. The survey's thresholds are defaults;
all are parameters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class HouseRule:
    """When an approximated outline counts as a house."""

    perimeter_tolerance: float = 0.10
    """Approximated perimeter within this fraction of the contour's own perimeter."""
    min_angle_deg: float = 60.0
    max_angle_deg: float = 100.0
    max_side_ratio: float = 6.0
    """Longest / shortest side at most this (and so at least its inverse)."""
    epsilon_fraction: float = 0.02
    """RDP tolerance as a fraction of the contour perimeter."""
    max_hole_fraction: float = 0.1
    """A roof's holes cover at most this fraction of its outline (a road loop's cover most)."""


def _corner_angles(poly: np.ndarray) -> np.ndarray:
    """Interior-ish angle at each vertex of a closed polygon, degrees in [0, 180]."""
    prev = np.roll(poly, 1, axis=0) - poly
    nxt = np.roll(poly, -1, axis=0) - poly
    cos = np.einsum("ij,ij->i", prev, nxt) / (
        np.linalg.norm(prev, axis=1) * np.linalg.norm(nxt, axis=1) + 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def is_house_like(contour: np.ndarray, rule: HouseRule = HouseRule()) -> bool:
    """Whether an OpenCV contour simplifies to a rectangle-like polygon."""
    perimeter = cv2.arcLength(contour, closed=True)
    if perimeter <= 0:
        return False
    approx = cv2.approxPolyDP(contour, rule.epsilon_fraction * perimeter, closed=True)
    poly = approx.reshape(-1, 2).astype(float)
    if len(poly) < 3 or not cv2.isContourConvex(approx):
        return False  # an L or a T of right angles is a road junction, not a roof
    approx_perimeter = cv2.arcLength(approx, closed=True)
    if abs(approx_perimeter - perimeter) > rule.perimeter_tolerance * perimeter:
        return False
    angles = _corner_angles(poly)  # convex, so these are the interior angles
    if not ((angles >= rule.min_angle_deg) & (angles <= rule.max_angle_deg)).all():
        return False
    sides = np.linalg.norm(np.roll(poly, -1, axis=0) - poly, axis=1)
    return bool(sides.max() <= rule.max_side_ratio * max(sides.min(), 1e-9))


def _hole_area(contours: Sequence[np.ndarray], hierarchy: np.ndarray, outer: int) -> float:
    """Total area of the holes of blob ``outer`` (its children in a RETR_CCOMP hierarchy)."""
    area, child = 0.0, hierarchy[outer][2]
    while child != -1:
        area += cv2.contourArea(contours[child])
        child = hierarchy[child][0]
    return area


def remove_houses(mask: np.ndarray, rule: HouseRule = HouseRule()) -> np.ndarray:
    """The mask without its rectangle-like solid blobs (filled with their small holes).

    Every blob's outer outline is examined, including blobs lying inside a hole of another
    blob: a roof in a town block is enclosed by the block's roads, and ``RETR_EXTERNAL``
    would never show it. A roof is solid; a blob with large holes is a loop of road around a
    block, however square its outline.
    """
    contours, hierarchy = cv2.findContours(mask.astype(np.uint8), cv2.RETR_CCOMP,
                                           cv2.CHAIN_APPROX_NONE)
    out = mask.astype(np.uint8)
    if not contours:
        return out.astype(bool)
    links = hierarchy[0]
    for i, contour in enumerate(contours):
        if links[i][3] != -1 or not is_house_like(contour, rule):
            continue
        if _hole_area(contours, links, i) > rule.max_hole_fraction * cv2.contourArea(contour):
            continue
        cv2.drawContours(out, contours, i, 0, thickness=cv2.FILLED)
    return out.astype(bool)
