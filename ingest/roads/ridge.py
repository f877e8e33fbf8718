"""Sub-pixel road centres and widths from cross-sections of a soft road field.

The skeleton of a thresholded mask is quantised to the working grid: a road at 10° to the
grid comes out as a staircase of 1-pixel steps, and its centre can be half a pixel off. The
soft field the mask came from (the road probability, or for the colour classifiers a
smoothed mask) holds the sub-pixel information: cut it perpendicular to the road, and the
two places where the profile falls below the mask's threshold are the road's edges. Their
midpoint is the centre and their distance the width, both continuous, and both insensitive
to a plateau (a broad road whose probability is flat at 1 has no single peak to fit, but it
has two edges). The field is sampled through a cubic spline, so the edges are located to a
small fraction of a pixel.

A cross-section is refused where it cannot be trusted: its centre is not road, an edge is
not found within ``max_half_px``, or the profile reaches no-data (outside the imagery's
valid mask) before it reaches an edge; the caller then keeps the skeleton's own position
there, or nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import map_coordinates, spline_filter

SOFT_MASK_SIGMA_PX = 1.0
"""Blur that turns a binary mask's pixel staircase into an edge crossing 0.5 at the pixel
boundary, with a slope the sub-pixel search can interpolate."""
_CHUNK = 4096
"""Cross-sections sampled per batch: bounds the (sections x samples) arrays."""


@dataclass(frozen=True)
class RoadField:
    """What the centre refinement samples: a soft road field on the working grid, the level
    at which it stops being road, and where the imagery has data."""

    values: np.ndarray
    """Float field, road high (probability 0..1, or a smoothed 0/1 mask)."""
    level: float
    """The threshold the road mask was cut at: the edges are where ``values`` crosses it."""
    valid: np.ndarray | None
    """False outside the imagery (no-data); None when every pixel has data."""

    def coefficients(self) -> np.ndarray:
        """Cubic spline coefficients of ``values`` for :func:`cross_sections` (one pass over
        the grid, shared by every section). No-data pixels count as not road."""
        field = self.values.astype(np.float64)
        if self.valid is not None:
            field = np.where(self.valid, field, 0.0)
        return spline_filter(field, order=3, mode="nearest")


def soft_mask(mask: np.ndarray) -> np.ndarray:
    """A binary road mask as a soft field crossing 0.5 at its edges (for the classifiers that
    give no probability)."""
    return cv2.GaussianBlur(mask.astype(np.float32), (0, 0), SOFT_MASK_SIGMA_PX)


@dataclass(frozen=True)
class Sections:
    """Result of :func:`cross_sections`, one row per section."""

    centres: np.ndarray
    """(n, 2) refined centres, pixel-corner (x, y) coordinates (input point where not ok)."""
    widths_px: np.ndarray
    """Edge-to-edge distance along the normal (NaN where not ok)."""
    ok: np.ndarray
    """Both edges found, on data, with road at the centre."""


def sample(coefficients: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Cubic-spline value of the field at pixel-corner (x, y) points (any leading shape)."""
    rows, cols = xy[..., 1] - 0.5, xy[..., 0] - 0.5
    return map_coordinates(coefficients, [rows.ravel(), cols.ravel()], order=3,
                           prefilter=False, mode="nearest").reshape(rows.shape)


_COARSE = 5
"""Fine samples per coarse step of the edge search: the profile is first read every
``_COARSE`` samples, and only the step where it first falls below the level is read finely.
The field is a probability on a 0.5 m grid, smooth at the 0.1 px fine step; reading every
fine sample (800 per section) took a third of the road graph's time."""


def _edge(coefficients: np.ndarray, level: float, points: np.ndarray, normals: np.ndarray,
          half: int, step_px: float, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sub-sample position (in fine samples from each point, along its normal) of the first
    crossing below ``level``, and whether it was found on data (``inside``: the fine samples
    0..``half`` that are on data)."""
    ks = np.unique(np.append(np.arange(0, half + 1, _COARSE), half))
    xy = points[:, None, :] + (ks * step_px)[None, :, None] * normals[:, None, :]
    below = sample(coefficients, xy) < level
    found = below.any(axis=1)
    lo = ks[np.maximum(np.argmax(below, axis=1), 1) - 1]
    # The fine samples of the coarse step where the profile first fell below the level.
    k = np.minimum(lo[:, None] + np.arange(_COARSE + 1), half)
    xy = points[:, None, :] + (k * step_px)[..., None] * normals[:, None, :]
    values = sample(coefficients, xy)
    jj = np.argmax(values < level, axis=1)
    j = lo + jj
    off_data = ~inside
    first_off = np.where(off_data.any(axis=1), np.argmax(off_data, axis=1), half + 1)
    ok = found & (jj > 0) & (j < first_off)
    rows = np.arange(len(values))
    jj = np.maximum(jj, 1)
    a, b = values[rows, jj - 1], values[rows, jj]
    frac = np.clip((a - level) / np.where(a - b > 1e-12, a - b, 1.0), 0.0, 1.0)
    return lo + jj - 1 + frac, ok


def cross_sections(coefficients: np.ndarray, field: RoadField, points: np.ndarray,
                   normals: np.ndarray, max_half_px: float, step_px: float = 0.1) -> Sections:
    """Refine ``points`` (pixel-corner x, y) to the midpoint between the road edges found
    along ``normals`` (unit vectors), searching ``max_half_px`` each way."""
    n = len(points)
    centres = points.astype(float).copy()
    widths = np.full(n, np.nan)
    ok = np.zeros(n, bool)
    half = max(int(np.ceil(max_half_px / step_px)), 2)
    t = np.arange(-half, half + 1) * step_px
    shape = field.values.shape
    for lo in range(0, n, _CHUNK):
        p, nv = points[lo:lo + _CHUNK], normals[lo:lo + _CHUNK]
        xy = p[:, None, :] + t[None, :, None] * nv[:, None, :]
        col = np.floor(xy[..., 0]).astype(np.intp)
        row = np.floor(xy[..., 1]).astype(np.intp)
        inside = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
        if field.valid is not None:
            inside[inside] = field.valid[row[inside], col[inside]]
        right, ok_r = _edge(coefficients, field.level, p, nv, half, step_px, inside[:, half:])
        left, ok_l = _edge(coefficients, field.level, p, -nv, half, step_px,
                           inside[:, half::-1])
        good = ok_r & ok_l & (sample(coefficients, p) >= field.level)
        mid = (right - left) / 2 * step_px
        centres[lo:lo + _CHUNK] = np.where(good[:, None], p + mid[:, None] * nv, p)
        widths[lo:lo + _CHUNK] = np.where(good, (right + left) * step_px, np.nan)
        ok[lo:lo + _CHUNK] = good
    return Sections(centres, widths, ok)
