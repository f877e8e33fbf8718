"""Training data for the road model: labelled scenes at one ground resolution, and crops.

Everything is resampled to the model's resolution (metres per pixel) from each image's own
m/px, because a convolution learns road *widths in pixels*: a model that saw 1 m pixels must
be shown 1 m pixels. The photometric normalisation (:func:`normalise`) is shared with
inference so that a 16-bit or single-band image means the same thing to the network as the
8-bit RGB it was trained on. Pure numpy/OpenCV: the crop sampler and the scene loader are
tested without torch.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ingest.roads import RoadsInputError
from ingest.roads.evaluate import distance_to_lines_m, line_pixels
from ingest.roads.georef import Image, read_band, read_image, resize
from ingest.roads.model.procedural import procedural_scene

STRETCH_PERCENTILES = (0.5, 99.5)
"""Per-image contrast stretch: robust to a few saturated pixels (white roofs, glints)."""
LINE_ROAD_M, LINE_UNSURE_M = 2.0, 6.0
"""Centerline labels (SpaceNet): road within 2 m of a line, unlabelled out to 6 m (roads are
wider than 4 m, but how much wider the file does not say)."""
NODATA_WHITE = 250 / 255
"""Massachusetts tiles mark missing imagery pure white: not road, not background either."""


@dataclass(frozen=True)
class Scene:
    """One labelled image on the model grid."""

    name: str
    source: str
    rgb: np.ndarray
    """(rows, cols, 3) uint8, normalised (:func:`normalise`)."""
    road: np.ndarray
    """(rows, cols) uint8 1 = road."""
    weight: np.ndarray
    """(rows, cols) uint8 1 = counts in the loss, 0 = unknown (no data, unsure margin)."""


def rgb_bands(pixels: np.ndarray) -> np.ndarray:
    """Three bands from any band count: one band is repeated as grey; four or more keep the
    first three (RGB then NIR is the usual order)."""
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    return pixels[..., :3] if pixels.shape[-1] >= 3 else np.repeat(pixels[..., :1], 3, axis=-1)


def stretch_limits(pixels: np.ndarray, valid: np.ndarray | None = None
                   ) -> tuple[float, float]:
    """(low, high) grey levels of the contrast stretch of :func:`rgb_bands` of ``pixels``,
    from a ~250k-pixel subsample (so a 40 MP mosaic costs no copy).

    The stretch makes a 12-bit-in-16 image, a dark exposure and an 8-bit JPEG look alike. A
    flat or empty image (nothing to stretch) gets (0, 1): left as it is.
    """
    step = max(1, int(math.sqrt(pixels.shape[0] * pixels.shape[1] / 250_000)))
    sample = rgb_bands(pixels[::step, ::step])
    if valid is not None:
        sample = sample[valid[::step, ::step]]
    if sample.size == 0:
        return 0.0, 1.0
    lo, hi = (float(v) for v in np.percentile(sample, STRETCH_PERCENTILES))
    return (lo, hi) if hi - lo > 1e-6 else (0.0, 1.0)


def stretch(rgb: np.ndarray, limits: tuple[float, float]) -> np.ndarray:
    """A float32 copy of ``rgb`` mapped linearly from ``limits`` to [0, 1] and clipped."""
    lo, hi = limits
    out = rgb.astype(np.float32)
    out -= lo
    out *= 1.0 / (hi - lo)
    return np.clip(out, 0, 1, out=out)


def normalise(pixels: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """Any band count, any scale (float in [0, 1] as :func:`read_image` gives) -> RGB float32
    in [0, 1], contrast-stretched between the image's 0.5th and 99.5th percentiles."""
    return stretch(rgb_bands(pixels), stretch_limits(pixels, valid))


def to_model_grid(image: Image, resolution_m: float) -> tuple[np.ndarray, np.ndarray | None]:
    """Normalised RGB and validity resampled (area average / nearest) to ``resolution_m``."""
    rgb = normalise(image.pixels, image.valid)
    rows, cols = rgb.shape[:2]
    shape = (max(1, round(rows * image.resolution_m / resolution_m)),
             max(1, round(cols * image.resolution_m / resolution_m)))
    if shape == (rows, cols):
        return rgb, image.valid
    finer = shape[0] > rows
    rgb = resize(rgb, shape, cv2.INTER_LINEAR if finer else cv2.INTER_AREA)
    valid = None if image.valid is None else resize(
        image.valid.astype(np.uint8), shape, cv2.INTER_NEAREST).astype(bool)
    return rgb, valid


def _line_labels(path: Path, image: Image) -> tuple[np.ndarray, np.ndarray]:
    """(road, known) from GeoJSON centerlines in the image's CRS."""
    if image.transform is None:
        raise RoadsInputError(f"{path}: centerline labels need a georeferenced image")
    _, metres = distance_to_lines_m(line_pixels(path, ~image.transform),
                                    image.pixels.shape[:2], image.resolution_m)
    return metres <= LINE_ROAD_M, (metres <= LINE_ROAD_M) | (metres > LINE_UNSURE_M)


def load_scene(root: Path, pair: dict, resolution_m: float) -> Scene:
    """One ``pairs.json`` entry on the model grid (see module doc)."""
    image = read_image(root / pair["image"], float(pair["m_per_px"]))
    mask_path = root / pair["mask"]
    if mask_path.suffix == ".geojson":
        road, known = _line_labels(mask_path, image)
    else:
        band = read_band(mask_path)[0]
        road, known = band >= 128, np.ones(band.shape, bool)
    if pair.get("source") == "massachusetts":
        known &= ~(image.pixels[..., :3] >= NODATA_WHITE).all(axis=-1)
    if image.valid is not None:
        known &= image.valid
    rgb, _ = to_model_grid(image, resolution_m)
    shape = rgb.shape[:2]
    road_f = resize(road.astype(np.float32), shape, cv2.INTER_AREA)
    known_f = resize(known.astype(np.float32), shape, cv2.INTER_AREA)
    return Scene(name=pair["image"], source=pair.get("source", Path(pair["image"]).parts[0]),
                 rgb=np.round(rgb * 255).astype(np.uint8),
                 road=(road_f >= 0.5).astype(np.uint8),
                 weight=(known_f >= 0.99).astype(np.uint8))


def file_sha16(path: Path) -> str:
    """First 16 hex digits of a file's sha256 (the form ``pairs.json`` records)."""
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def image_hashes(folder: Path) -> set[str]:
    """sha16 of every image under ``folder``: the validation set to keep out of training."""
    suffixes = {".jpg", ".jpeg", ".png", ".tif", ".tiff"}
    return {file_sha16(p) for p in folder.rglob("*") if p.suffix.lower() in suffixes}


def training_pairs(root: Path, exclude_sha16: Iterable[str] = ()) -> list[dict]:
    """``root/pairs.json`` minus every pair whose image is byte-identical to an excluded one."""
    path = root / "pairs.json"
    if not path.is_file():
        raise RoadsInputError(f"{root} has no pairs.json (list of image/mask/m_per_px)")
    excluded = set(exclude_sha16)
    pairs = json.loads(path.read_text())
    return [p for p in pairs if file_sha16(root / p["image"]) not in excluded]


def is_holdout(pair: dict) -> bool:
    """The model-selection split: ``"split": "holdout"`` in the pair, else (the shared
    training set) one Massachusetts tile and every 12th EPFL and CIL-2022 tile.

    Fixed by name so every run holds out the same scenes; threshold and checkpoint are chosen
    on these, never on the validation images reported in the model card.
    """
    if "split" in pair:
        return pair["split"] == "holdout"
    name = Path(pair["image"]).stem
    if pair.get("source") == "massachusetts":
        return name == "mass_14_sat"
    if pair.get("source") in ("epfl_roadseg", "cil2022"):
        return int(name.removesuffix("_sat").rsplit("_", 1)[-1]) % 12 == 0
    return False


@dataclass(frozen=True)
class Augment:
    """Random changes a training crop goes through: probabilities and ranges.

    Geometry (scale, 90° turns, flips) teaches that a road is a road at any heading and a
    little bigger or smaller. The photometric ones imitate what differs between the training
    sources and a user's imagery: sensor colour and gain, season (hue), haze, a coarser
    sensor upsampled to the model's grid (``degrade``), JPEG compression, blur, noise and
    single-band imagery. ``ugvmap roads train --augment NAME=VALUE`` changes one.
    """

    scale_min: float = 0.7
    scale_max: float = 1.4
    hue: float = 0.08
    """Rotate hue by up to this fraction of the colour wheel (0 = off)."""
    saturation: float = 0.4
    """Scale saturation by 1 +- this."""
    grey_p: float = 0.05
    haze_p: float = 0.15
    """Blend towards a bright veil (haze, thin cloud, over-exposure) by up to 40 %."""
    degrade_p: float = 0.2
    """Down- then up-sample by 1.5-2.5x: a coarser sensor seen on the model's grid."""
    jpeg_p: float = 0.25
    """Re-encode as JPEG at quality 30-90."""
    blur_p: float = 0.3
    noise_p: float = 0.3
    shuffle_p: float = 0.0
    """Permute the colour channels: a road is a road in any palette (shape over colour)."""
    invert_p: float = 0.0
    """Invert brightness: dirt tracks are lighter than their ground, asphalt darker."""
    procedural_p: float = 0.0
    """Share of crops drawn by :func:`ingest.roads.model.procedural.procedural_scene` instead
    of cut from a real scene: roads of every surface over every ground (domain
    randomisation), for the looks the real data lacks (rural tracks, deserts, fields)."""


class CropSampler:
    """Random augmented crops (:class:`Augment`) of the training scenes.

    Scenes are drawn with probability proportional to area^0.75 so the many small EPFL and CIL
    tiles do not drown the few large Massachusetts ones, nor the reverse, times
    ``source_weight[scene.source]`` (default 1): a handful of scenes of a kind the rest lacks
    (12 rural tiles among 259 urban ones) is otherwise drawn too rarely to teach. Scenes
    smaller than a crop are padded (reflected image, weight 0). A share
    ``augment.procedural_p`` of the crops is drawn procedurally instead, at the model's
    ``resolution_m``.
    """

    def __init__(self, scenes: list[Scene], size: int, seed: int,
                 augment: Augment = Augment(), resolution_m: float = 0.5,
                 source_weight: dict[str, float] | None = None) -> None:
        self.scenes = scenes
        self.size = size
        self.augment = augment
        self.resolution_m = resolution_m
        self.rng = np.random.default_rng(seed)
        weight = source_weight or {}
        area = np.array([s.road.size ** 0.75 * weight.get(s.source, 1.0) for s in scenes])
        self.p = area / area.sum()

    def crop(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rgb float32 (3, s, s) in [0, 1], road float32 (1, s, s), weight float32 (1, s, s))."""
        rng = self.rng
        if self.augment.procedural_p and rng.random() < self.augment.procedural_p:
            rgb, road, weight = procedural_scene(rng, self.size, self.resolution_m)
        else:
            rgb, road, weight = self._real_crop()
        k = int(rng.integers(4))
        rgb, road, weight = np.rot90(rgb, k), np.rot90(road, k), np.rot90(weight, k)
        if rng.random() < 0.5:
            rgb, road, weight = rgb[:, ::-1], road[:, ::-1], weight[:, ::-1]
        rgb = self._colour(np.ascontiguousarray(rgb))
        return (np.ascontiguousarray(rgb.transpose(2, 0, 1)),
                np.ascontiguousarray(road)[None], np.ascontiguousarray(weight)[None])

    def _real_crop(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A randomly placed, randomly scaled crop of a real scene: (rgb, road, weight)."""
        rng, aug = self.rng, self.augment
        scene = self.scenes[rng.choice(len(self.scenes), p=self.p)]
        scale = math.exp(rng.uniform(math.log(aug.scale_min), math.log(aug.scale_max)))
        side = max(8, round(self.size * scale))
        rows, cols = scene.road.shape
        r0 = int(rng.integers(0, max(rows - side, 0) + 1))
        c0 = int(rng.integers(0, max(cols - side, 0) + 1))
        rgb = scene.rgb[r0:r0 + side, c0:c0 + side].astype(np.float32) / 255
        road = scene.road[r0:r0 + side, c0:c0 + side].astype(np.float32)
        weight = scene.weight[r0:r0 + side, c0:c0 + side].astype(np.float32)
        h, w = road.shape
        if (h, w) != (side, side):
            pad = ((0, side - h), (0, side - w))
            rgb = np.pad(rgb, (*pad, (0, 0)), mode="reflect" if min(h, w) > 1 else "edge")
            road = np.pad(road, pad)
            weight = np.pad(weight, pad)
        if side != self.size:
            shape = (self.size, self.size)
            rgb = resize(rgb, shape, cv2.INTER_AREA if side > self.size else cv2.INTER_LINEAR)
            road = resize(road, shape, cv2.INTER_LINEAR)
            weight = (resize(weight, shape, cv2.INTER_LINEAR) >= 0.99).astype(np.float32)
        return rgb, road, weight

    def _colour(self, rgb: np.ndarray) -> np.ndarray:
        """Photometric changes: sensors, sun, season and compression differ; road shape does
        not."""
        rng, aug = self.rng, self.augment
        if aug.hue:
            hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
            hsv[..., 0] = (hsv[..., 0] + 360 * rng.uniform(-aug.hue, aug.hue)) % 360
            rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
        grey = rgb.mean(axis=-1, keepdims=True)
        if rng.random() < aug.grey_p:
            rgb = np.repeat(grey, 3, axis=-1)
        else:
            rgb = grey + (rgb - grey) * rng.uniform(1 - aug.saturation, 1 + aug.saturation)
        rgb = rgb * rng.normal(1.0, 0.06, size=3).astype(np.float32)
        mean = float(rgb.mean())
        rgb = (rgb - mean) * rng.uniform(0.75, 1.25) + mean + rng.uniform(-0.1, 0.1)
        rgb = np.clip(rgb, 0, 1) ** rng.uniform(0.8, 1.25)
        if rng.random() < aug.haze_p:
            veil = rng.uniform(0.7, 1.0)
            rgb = rgb + (veil - rgb) * rng.uniform(0.1, 0.4)
        if rng.random() < aug.degrade_p:
            small = max(8, round(self.size / rng.uniform(1.5, 2.5)))
            rgb = resize(resize(rgb, (small, small), cv2.INTER_AREA), (self.size, self.size),
                         cv2.INTER_LINEAR)
        if rng.random() < aug.blur_p:
            rgb = cv2.GaussianBlur(rgb, (0, 0), rng.uniform(0.3, 1.2))
        if rng.random() < aug.noise_p:
            rgb = rgb + rng.normal(0, rng.uniform(0.005, 0.03), rgb.shape)
        if rng.random() < aug.shuffle_p:
            rgb = rgb[..., rng.permutation(3)]
        if rng.random() < aug.invert_p:
            rgb = 1 - rgb
        if rng.random() < aug.jpeg_p:
            rgb = _jpeg(rgb, int(rng.integers(30, 91)))
        return np.clip(rgb, 0, 1).astype(np.float32)


def _jpeg(rgb: np.ndarray, quality: int) -> np.ndarray:
    """``rgb`` after a JPEG round trip at ``quality`` (blocking and ringing artefacts)."""
    u8 = np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
    ok, buf = cv2.imencode(".jpg", u8, [cv2.IMWRITE_JPEG_QUALITY, quality])
    decoded = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if ok else None
    return rgb if decoded is None else decoded.astype(np.float32) / 255
