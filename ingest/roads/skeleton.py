"""Thinning to a one-pixel, 8-connected centerline and iterative spur pruning.

Thinning a road blob leaves "hairs": short branches from every bump of the outline. A hair
runs from an endpoint to the nearest junction; a real dead-end road does too, but is longer.
Pruning with a threshold grown step by step (instead of once at the maximum) removes the
smallest hairs first, so the false junctions they created disappear before a longer branch is
judged, and real road ends survive.
"""

from __future__ import annotations

import cv2
import numpy as np
from skimage.morphology import skeletonize

_RING = ((-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1))


def thin(mask: np.ndarray) -> np.ndarray:
    """One-pixel-wide 8-connected skeleton that keeps the mask's connectivity."""
    return skeletonize(mask.astype(bool))


def neighbour_count(skel: np.ndarray) -> np.ndarray:
    """Number of 8-neighbours of each pixel that are on the skeleton (uint8)."""
    s = skel.astype(np.uint8)
    kernel = np.ones((3, 3), np.float32)
    kernel[1, 1] = 0
    return cv2.filter2D(s, cv2.CV_8U, kernel, borderType=cv2.BORDER_CONSTANT)


class PixelWalker:
    """Constant-time 8-neighbour look-ups on a flat, zero-padded copy of a skeleton."""

    def __init__(self, skel: np.ndarray):
        self.cols = skel.shape[1] + 2
        padded = np.zeros((skel.shape[0] + 2, self.cols), bool)
        padded[1:-1, 1:-1] = skel
        self.on = padded.ravel()
        self.offsets = tuple(dr * self.cols + dc for dr, dc in _RING)

    def flat(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Flat padded indices of (row, col) pixels."""
        return (np.asarray(rows) + 1) * self.cols + np.asarray(cols) + 1

    def unflat(self, idx: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """(rows, cols) of flat padded indices."""
        idx = np.asarray(idx)
        return idx // self.cols - 1, idx % self.cols - 1

    def neighbours(self, i: int) -> list[int]:
        """Skeleton 8-neighbours of flat index ``i``."""
        on = self.on
        return [i + o for o in self.offsets if on[i + o]]


def trace(walker: PixelWalker, start: int, stop: np.ndarray | None = None,
          limit: int | None = None) -> tuple[list[int], bool]:
    """Follow a chain of skeleton pixels from ``start``.

    Stops before a pixel flagged in ``stop`` (returning ``True``), at the chain's end, or after
    ``limit`` pixels. Where a corner offers two mutually adjacent next pixels both join the
    path and the walk continues from the one leading on.
    """
    path = [start]
    seen = {start}
    cur = start
    while limit is None or len(path) <= limit:
        nxt = [n for n in walker.neighbours(cur) if n not in seen]
        if not nxt:
            return path, False
        if stop is not None and any(stop[n] for n in nxt):
            return path, True
        seen.update(nxt)
        if len(nxt) > 1:
            nxt.sort(key=lambda n: sum(m not in seen for m in walker.neighbours(n)))
        path.extend(nxt)
        cur = nxt[-1]
    return path, False


def _prune_once(skel: np.ndarray, limit_px: int) -> int:
    """Remove every spur of at most ``limit_px`` pixels; returns how many were removed."""
    count = neighbour_count(skel)
    ends = np.flatnonzero((skel & (count == 1)).ravel())
    if len(ends) == 0:
        return 0
    walker = PixelWalker(skel)
    junction = np.zeros_like(walker.on)
    jr, jc = np.nonzero(skel & (count >= 3))
    junction[walker.flat(jr, jc)] = True
    removed = 0
    for r, c in zip(*np.unravel_index(ends, skel.shape), strict=True):
        path, at_junction = trace(walker, int(walker.flat(r, c)), junction, limit_px)
        if at_junction:
            rows, cols = walker.unflat(np.array(path))
            skel[rows, cols] = False
            removed += 1
    return removed


def prune_spurs(skel: np.ndarray, max_length_px: float, steps: int = 4) -> np.ndarray:
    """Iteratively remove endpoint-to-junction branches up to ``max_length_px`` long.

    The threshold grows in ``steps`` equal increments; at each one, pruning repeats until
    nothing changes, then the skeleton is re-thinned (removing a spur can leave a corner).
    """
    out = skel.astype(bool).copy()
    for step in range(1, steps + 1):
        limit = max(1, round(max_length_px * step / steps))
        changed = False
        while _prune_once(out, limit):
            changed = True
        if changed:
            out = thin(out)
    return out
