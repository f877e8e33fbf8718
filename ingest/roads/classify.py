"""Road / not-road pixel classification from a user's training sample.

Two classifiers:

* **spectral** — the survey's method: road pixels lie near a straight line in colour space
  (asphalt is grey at any brightness), so fit that line by total least squares and keep every
  pixel within ``k`` times the mean distance of the training pixels. It needs only road samples
  but confuses roads with anything grey (roofs, parking lots).
* **learned** — ilastik-style interactive pixel classification: multi-scale colour, edge,
  ridge (Hessian) and texture features, sized in metres so one model fits any resolution, and a
  gradient-boosted tree classifier trained on the labelled pixels. Computed tile by tile with a
  halo so memory stays bounded on town-sized mosaics.

Labels use one convention everywhere: 255 = road, 128 = not road, 0 = unlabelled.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import cv2
import numpy as np
from skimage.filters import apply_hysteresis_threshold
from tqdm import tqdm

from ingest.roads import RoadsInputError

if TYPE_CHECKING:  # scikit-learn takes 0.7 s to import: only the learned classifier needs it
    from sklearn.ensemble import HistGradientBoostingClassifier

ROAD, NOT_ROAD, UNLABELLED = 255, 128, 0
Box = tuple[int, int, int, int]


def training_labels(shape: tuple[int, int], road_boxes: Sequence[Box] = (),
                    not_road_boxes: Sequence[Box] = (),
                    mask: np.ndarray | None = None) -> np.ndarray:
    """Label image (255/128/0) from boxes ``x0,y0,x1,y1`` (pixels, end exclusive) and/or a mask.

    A label mask is read with the same convention; grey levels are snapped to the nearest of
    0/128/255 so a lossy (JPEG) label image still means what the user drew.
    """
    rows, cols = shape
    labels = np.zeros(shape, np.uint8)
    if mask is not None:
        if mask.shape[:2] != shape:
            raise RoadsInputError(
                f"training mask is {mask.shape[1]}x{mask.shape[0]} px but the image is "
                f"{cols}x{rows}")
        m = mask if mask.ndim == 2 else mask[..., 0]
        labels[m >= 192] = ROAD
        labels[(m >= 64) & (m < 192)] = NOT_ROAD
    for boxes, value in ((not_road_boxes, NOT_ROAD), (road_boxes, ROAD)):
        for x0, y0, x1, y1 in boxes:
            if not (0 <= x0 < x1 <= cols and 0 <= y0 < y1 <= rows):
                raise RoadsInputError(
                    f"training box {x0},{y0},{x1},{y1} is not inside the {cols}x{rows} image "
                    "(need 0 <= x0 < x1 <= width, 0 <= y0 < y1 <= height)")
            labels[y0:y1, x0:x1] = value
    if not (labels == ROAD).any():
        raise RoadsInputError("the training sample has no road pixels: give --train-box "
                              "around a bit of road, or a --train-mask with 255 = road")
    return labels


# --- spectral line -------------------------------------------------------------------------

@dataclass(frozen=True)
class SpectralLine:
    """A line through colour space and the mean distance of the road samples to it, ended
    where the background says so (:func:`bounded_by_background`; unbounded by default)."""

    origin: np.ndarray
    direction: np.ndarray
    mean_distance: float
    low: float = -math.inf
    high: float = math.inf
    """Positions along the line (from ``origin``) beyond which a colour is not road: the
    excess counts as distance."""

    def along(self, pixels: np.ndarray) -> np.ndarray:
        """Position of (n, bands) pixels along the line, from its origin."""
        return (pixels - self.origin) @ self.direction

    def distance(self, pixels: np.ndarray) -> np.ndarray:
        """Distance of every pixel (..., bands) to the line (to its bounded part), float32."""
        d = pixels.reshape(-1, pixels.shape[-1]) - self.origin
        if d.shape[1] == 1:
            dist = np.abs(d[:, 0])
        else:
            along = d @ self.direction
            perp2 = np.maximum(np.einsum("ij,ij->i", d, d) - along * along, 0)
            excess = np.maximum(self.low - along, 0) + np.maximum(along - self.high, 0)
            dist = np.sqrt(perp2 + excess * excess)
        return dist.reshape(pixels.shape[:-1]).astype(np.float32)


NOISE_FLOOR = 1.0 / 255
"""Smallest mean distance we trust: one 8-bit grey level (a flat sample has distance 0)."""


def fit_spectral_line(samples: np.ndarray) -> SpectralLine:
    """Total-least-squares line through (n, bands) samples: the first principal axis."""
    origin = samples.mean(axis=0)
    centred = samples - origin
    direction = np.linalg.svd(centred, full_matrices=False)[2][0] if len(samples) > 1 else (
        np.eye(samples.shape[1])[0])
    line = SpectralLine(origin, direction, 0.0)
    mean = float(line.distance(samples[None, ...]).mean())
    return SpectralLine(origin, direction, max(mean, NOISE_FLOOR))


BOUND_MIN_SHARE = 0.1
"""A side of the line is ended only when at least this share of the background samples lies
on the line beyond the road's middle on that side (else the line already separates them)."""
BOUND_MAX_ROAD_LOSS = 0.05
"""...at a cut that loses at most this share of the road samples..."""
BOUND_MAX_KEPT = 0.5
"""...and keeps at most this share of those background samples (else no clear cut)."""


def _cut(road: np.ndarray, background: np.ndarray) -> float | None:
    """The position along the line (``road``/``background``: positions, the background all
    below the road's median) that best parts the two: the least road lost below it plus
    background kept above it, losing at most ``BOUND_MAX_ROAD_LOSS`` of the road; None when
    no cut keeps less than ``BOUND_MAX_KEPT`` of the background."""
    road, background = np.sort(road), np.sort(background)
    candidates = np.unique(np.quantile(np.concatenate([road, background]),
                                       np.linspace(0, 1, 513)))
    lost = np.searchsorted(road, candidates) / len(road)
    kept = 1 - np.searchsorted(background, candidates) / len(background)
    error = np.where(lost <= BOUND_MAX_ROAD_LOSS, lost + kept, np.inf)
    best = int(np.argmin(error))
    return float(candidates[best]) if kept[best] <= BOUND_MAX_KEPT else None


def bounded_by_background(line: SpectralLine, road: np.ndarray, background: np.ndarray,
                          limit: float) -> SpectralLine:
    """``line`` ended where ``background`` samples (not road) lie on it: a grey verge or a
    grey ground darker or brighter than grey asphalt is on the asphalt's line, which is
    unbounded because shade moves a road's colour along it; where the background shows such
    a colour, the line stops between the road's and the background's brightness. Without
    such a background (green verges, most imagery) the line is unchanged, shade and all."""
    if len(background) == 0 or road.shape[1] == 1:
        return line
    near = background[line.distance(background[None])[0] <= limit]
    if len(near) < BOUND_MIN_SHARE * len(background):
        return line
    along_road, along_near = line.along(road), line.along(near)
    middle = float(np.median(along_road))
    low = high = None
    below, above = along_near[along_near < middle], along_near[along_near > middle]
    if len(below) >= BOUND_MIN_SHARE * len(background):
        low = _cut(along_road, below)
    if len(above) >= BOUND_MIN_SHARE * len(background):
        cut = _cut(-along_road, -above)
        high = None if cut is None else -cut
    if low is None and high is None:
        return line
    return SpectralLine(line.origin, line.direction, line.mean_distance,
                        -math.inf if low is None else low, math.inf if high is None else high)


def subsample_rows(values: np.ndarray, limit: int, seed: int) -> np.ndarray:
    """At most ``limit`` of ``values`` (rows), a random choice when there are more."""
    if len(values) <= limit:
        return values
    return values[np.random.default_rng(seed).choice(len(values), limit, replace=False)]


def spectral_classify(pixels: np.ndarray, labels: np.ndarray, k: float = 3.0,
                      max_samples: int = 200_000, seed: int = 0) -> np.ndarray:
    """Road mask: pixels within ``k`` x the training pixels' mean distance to their TLS line,
    the line ended where the not-road samples lie on it (:func:`bounded_by_background`)."""
    road = subsample_rows(pixels[labels == ROAD], max_samples, seed).astype(np.float64)
    line = fit_spectral_line(road)
    limit = k * line.mean_distance
    background = subsample_rows(pixels[labels == NOT_ROAD], max_samples, seed)
    line = bounded_by_background(line, road, background.astype(np.float64), limit)
    out = np.empty(pixels.shape[:2], bool)
    step = max(1, 4_000_000 // max(1, pixels.shape[1]))
    for r in range(0, pixels.shape[0], step):
        out[r:r + step] = line.distance(pixels[r:r + step]) <= limit
    return out


# --- learned pixel classifier --------------------------------------------------------------

SCALES_M = (1.0, 2.0, 4.0, 8.0)
"""Feature scales (Gaussian sigma) in metres: lane marking to a wide road's half width."""


def _blur(a: np.ndarray, sigma: float) -> np.ndarray:
    return cv2.GaussianBlur(a, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT)


def pixel_features(pixels: np.ndarray, resolution_m: float,
                   scales_m: Sequence[float] = SCALES_M) -> np.ndarray:
    """(rows, cols, F) float32 features: colour, chroma, and per scale the smoothed bands,
    gradient magnitude, both Hessian eigenvalues (ridges = roads) and local contrast.

    Scales are in metres so a model means the same thing at 0.3 m and 1 m per pixel.
    """
    pixels = pixels.astype(np.float32, copy=False)
    bands = [pixels[..., i] for i in range(pixels.shape[-1])]
    gray: np.ndarray = pixels.mean(axis=-1, dtype=np.float32)
    feats: list[np.ndarray] = [*bands]
    if len(bands) > 1:
        feats += [b - gray for b in bands]
    for scale in scales_m:
        sigma = max(scale / resolution_m, 0.5)
        feats += [_blur(b, sigma) for b in bands]
        g = _blur(gray, sigma)
        gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
        feats.append(sigma * np.sqrt(gx * gx + gy * gy))
        hxx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3)
        hyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3)
        hxy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3)
        half_trace = 0.5 * (hxx + hyy)
        root = np.sqrt(0.25 * (hxx - hyy) ** 2 + hxy * hxy)
        feats += [sigma * sigma * (half_trace + root), sigma * sigma * (half_trace - root)]
        feats.append(np.sqrt(np.maximum(_blur(gray * gray, sigma) - g * g, 0)))
    return np.stack(feats, axis=-1).astype(np.float32, copy=False)


LINE_LENGTHS_M = (12.0, 30.0)
"""Oriented line filters: a road is a long thin strip, a roof or a field is not."""
LINE_OFFSET_M = 6.0
"""Side lines sit this far from the centre line (beyond a typical half road width)."""
ORIENTATIONS = 8


@lru_cache(maxsize=32)
def _line_kernels(length_px: int, offset_px: int) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """(centre line, two side lines) averaging kernels for each orientation."""
    size = length_px + 2 * offset_px + 3
    c = size // 2
    kernels = []
    for k in range(ORIENTATIONS):
        theta = np.pi * k / ORIENTATIONS
        dx, dy = np.cos(theta) * length_px / 2, np.sin(theta) * length_px / 2
        nx, ny = -np.sin(theta) * offset_px, np.cos(theta) * offset_px
        pair = []
        for shifts in ((0,), (-1, 1)):
            kern = np.zeros((size, size), np.float32)
            for s in shifts:
                p0 = (round(c - dx + s * nx), round(c - dy + s * ny))
                p1 = (round(c + dx + s * nx), round(c + dy + s * ny))
                cv2.line(kern, p0, p1, 1.0, 1, cv2.LINE_AA)
            pair.append(kern / kern.sum())
        kernels.append(tuple(pair))
    return tuple(kernels)


def line_features(channel: np.ndarray, resolution_m: float) -> list[np.ndarray]:
    """Per line length: strongest and weakest centre-minus-sides contrast over orientations,
    and the centre mean along the best orientation (how road-like the strip itself is)."""
    out = []
    offset = max(1, round(LINE_OFFSET_M / resolution_m))
    for length_m in LINE_LENGTHS_M:
        length = max(3, round(length_m / resolution_m))
        best = np.full(channel.shape, -np.inf, np.float32)
        worst = np.full(channel.shape, np.inf, np.float32)
        along = np.zeros(channel.shape, np.float32)
        for centre_k, side_k in _line_kernels(length, offset):
            centre = cv2.filter2D(channel, cv2.CV_32F, centre_k, borderType=cv2.BORDER_REFLECT)
            contrast = centre - cv2.filter2D(channel, cv2.CV_32F, side_k,
                                             borderType=cv2.BORDER_REFLECT)
            better = contrast > best
            along[better] = centre[better]
            np.maximum(best, contrast, out=best)
            np.minimum(worst, contrast, out=worst)
        out += [best, worst, along]
    return out


def classifier_features(pixels: np.ndarray, resolution_m: float) -> np.ndarray:
    """All classifier features: per-pixel multi-scale stack plus oriented line responses of
    the (1 m smoothed) brightness."""
    gray: np.ndarray = pixels.mean(axis=-1, dtype=np.float32)
    lines = line_features(_blur(gray, max(0.5, 1.0 / resolution_m)), resolution_m)
    return np.concatenate([pixel_features(pixels, resolution_m), np.stack(lines, axis=-1)],
                          axis=-1)


def feature_halo_px(resolution_m: float, scales_m: Sequence[float] = SCALES_M) -> int:
    """Margin a tile needs so its features equal those of the whole image."""
    reach_m = max(3 * max(scales_m), max(LINE_LENGTHS_M) / 2 + LINE_OFFSET_M)
    return math.ceil(reach_m / resolution_m) + 2


def tiles(shape: tuple[int, int], size: int) -> Iterator[tuple[slice, slice]]:
    """Row/column slices covering ``shape`` in ``size`` blocks."""
    for r in range(0, shape[0], size):
        for c in range(0, shape[1], size):
            yield slice(r, min(r + size, shape[0])), slice(c, min(c + size, shape[1]))


def _tile_features(pixels: np.ndarray, rs: slice, cs: slice, resolution_m: float,
                   extra: np.ndarray | None = None) -> np.ndarray:
    """Features of one tile, computed on the tile plus halo and cropped back, followed by
    the tile's slice of ``extra`` (rows, cols, E) per-pixel features when given."""
    halo = feature_halo_px(resolution_m)
    r0, c0 = max(rs.start - halo, 0), max(cs.start - halo, 0)
    r1, c1 = min(rs.stop + halo, pixels.shape[0]), min(cs.stop + halo, pixels.shape[1])
    f = classifier_features(pixels[r0:r1, c0:c1], resolution_m)
    f = f[rs.start - r0:rs.stop - r0, cs.start - c0:cs.stop - c0]
    return f if extra is None else np.concatenate([f, extra[rs, cs]], axis=-1)


def _balanced_sample(labels: np.ndarray, per_class: int, seed: int) -> np.ndarray:
    """Flat indices of up to ``per_class`` road and ``per_class`` not-road pixels."""
    rng = np.random.default_rng(seed)
    flat = labels.ravel()
    picked = []
    for value in (ROAD, NOT_ROAD):
        idx = np.flatnonzero(flat == value)
        picked.append(rng.choice(idx, min(per_class, len(idx)), replace=False))
    return np.sort(np.concatenate(picked))


def train_pixel_classifier(pixels: np.ndarray, labels: np.ndarray, resolution_m: float,
                           per_class: int = 20_000, tile: int = 1024, seed: int = 0,
                           extra: np.ndarray | None = None) -> HistGradientBoostingClassifier:
    """Fit gradient-boosted trees on features of a balanced subsample of labelled pixels
    (``extra``: more per-pixel features, e.g. the road model's, appended to ours)."""
    chosen = _balanced_sample(labels, per_class, seed)
    rows, cols = np.unravel_index(chosen, labels.shape)
    xs, ys = [], []
    for rs, cs in tiles(labels.shape, tile):
        inside = (rows >= rs.start) & (rows < rs.stop) & (cols >= cs.start) & (cols < cs.stop)
        if not inside.any():
            continue
        f = _tile_features(pixels, rs, cs, resolution_m, extra)
        xs.append(f[rows[inside] - rs.start, cols[inside] - cs.start])
        ys.append(labels[rows[inside], cols[inside]] == ROAD)
    from sklearn.ensemble import HistGradientBoostingClassifier

    model = HistGradientBoostingClassifier(max_iter=60, learning_rate=0.2, max_leaf_nodes=31,
                                           l2_regularization=1.0, early_stopping=False,
                                           random_state=seed)
    return model.fit(np.concatenate(xs), np.concatenate(ys))


def road_probability(pixels: np.ndarray, model: HistGradientBoostingClassifier,
                     resolution_m: float, tile: int = 1024, progress: bool = False,
                     extra: np.ndarray | None = None) -> np.ndarray:
    """Per-pixel road probability, float32, tile by tile so memory is bounded."""
    out = np.empty(pixels.shape[:2], np.float32)
    blocks = list(tiles(pixels.shape[:2], tile))
    for rs, cs in tqdm(blocks, desc="classify", unit="tile", disable=not progress, leave=False):
        f = _tile_features(pixels, rs, cs, resolution_m, extra)
        p = model.predict_proba(f.reshape(-1, f.shape[-1]))[:, 1]
        out[rs, cs] = p.reshape(f.shape[:2])
    return out


def learned_classify(pixels: np.ndarray, labels: np.ndarray, resolution_m: float,
                     threshold: float = 0.5, seed_threshold: float = 0.85,
                     progress: bool = False) -> np.ndarray:
    """Road mask from the learned classifier's probability, smoothed by 1 m against speckle.

    Hysteresis: pixels above ``threshold`` count only when connected to a confident
    (``seed_threshold``) pixel, so faint road stretches survive and grey clutter does not.
    """
    if not (labels == NOT_ROAD).any():
        raise RoadsInputError("the learned classifier needs not-road pixels too: add "
                              "--not-road-box, a --train-mask with 128 = not road, or use "
                              "--classifier spectral")
    model = train_pixel_classifier(pixels, labels, resolution_m)
    prob = road_probability(pixels, model, resolution_m, progress=progress)
    smooth = _blur(prob, max(1.0 / resolution_m, 0.5))
    return apply_hysteresis_threshold(smooth, threshold, max(seed_threshold, threshold))
