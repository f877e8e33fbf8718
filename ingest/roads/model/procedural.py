"""Procedural training scenes: roads of every look over ground of every kind, with exact labels.

Why: the shared training set is 240 urban North-American Google tiles and 14 Massachusetts
ones; nothing in it is a dirt track across a desert, a farm road between fields or a road at
a colour the model has never seen, and the model learned "road = grey asphalt among houses"
(roads-v2's first snapshot found no road at all in a grey band across green grass, where the
from-scratch roads-v1 did, and nothing in DeepGlobe's rural tiles). Domain randomisation is
the standard remedy when the target looks are missing from the data: draw many scenes whose
only constant is the road's *shape* — a band of near-constant width and colour, smooth,
running through the scene and joining other roads — and whose ground, road surface, clutter
and colours are random, so the network has to learn that shape. Real crops still make up most
of every batch (``Augment.procedural_p``), so the real looks are not forgotten.

Everything is drawn at the model's ground resolution (``resolution_m``) so widths are in
metres: lanes of 2.5-14 m, houses of 6-20 m, trees of 2-8 m. Distractors that are *not* roads
are drawn on purpose: grey roofs (the classic false positive), field parcels with straight
edges, hairlines (fences, walls), and winding dry river beds (a DeepGlobe tile has one).
Pure numpy/OpenCV: deterministic for a given generator state, tested without torch.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

# Ground palettes (RGB 0-1): vegetation, dry grass, desert, soil, rock, snow-dusted, concrete.
GROUNDS = np.array([
    (0.24, 0.40, 0.16), (0.33, 0.45, 0.22), (0.47, 0.47, 0.28), (0.62, 0.52, 0.36),
    (0.55, 0.42, 0.30), (0.40, 0.33, 0.25), (0.50, 0.50, 0.46), (0.80, 0.80, 0.80),
    (0.70, 0.62, 0.48), (0.20, 0.30, 0.18)], np.float32)
ROOFS = np.array([(0.55, 0.55, 0.55), (0.75, 0.74, 0.72), (0.62, 0.30, 0.22),
                  (0.35, 0.33, 0.33), (0.85, 0.85, 0.86), (0.45, 0.40, 0.55)], np.float32)


def _texture(rng: np.random.Generator, size: int, sigma: float) -> np.ndarray:
    """Zero-mean, unit-deviation noise blurred to ``sigma`` pixels."""
    noise = rng.normal(0, 1, (size, size)).astype(np.float32)
    tex = cv2.GaussianBlur(noise, (0, 0), max(sigma, 0.3))
    return tex / (tex.std() + 1e-6)


def _ground(rng: np.random.Generator, size: int) -> np.ndarray:
    """Land cover: a base colour with multi-scale texture, and sometimes field parcels (straight
    edges at a random angle, each its own colour and row stripes)."""
    base = GROUNDS[rng.integers(len(GROUNDS))] * rng.uniform(0.8, 1.2, 3)
    img = np.empty((size, size, 3), np.float32)
    img[:] = base
    for sigma, amp in ((rng.uniform(1, 3), 0.04), (rng.uniform(8, 30), 0.08)):
        img += _texture(rng, size, sigma)[..., None] * amp * rng.uniform(0.3, 1.5, 3)
    if rng.random() < 0.4:
        angle = rng.uniform(0, math.pi)
        u = np.cos(angle), np.sin(angle)
        yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
        along, across = xx * u[0] + yy * u[1], -xx * u[1] + yy * u[0]
        cell = rng.uniform(30, 120)
        parcel = (np.floor(along / cell) * 7 + np.floor(across / rng.uniform(30, 120))).astype(int)
        colours = GROUNDS[rng.integers(len(GROUNDS), size=64)] * rng.uniform(0.8, 1.2, (64, 3))
        fields = colours[parcel % 64]
        stripes = 1 + 0.06 * np.sin(across * 2 * math.pi / rng.uniform(3, 8))[..., None]
        img = img + (fields * stripes - base) * rng.uniform(0.5, 1.0)
    return img


def _curve(rng: np.random.Generator, size: int) -> np.ndarray:
    """A smooth road centreline crossing the scene: a cubic Bezier between two points outside
    (or, now and then, ending inside: a dead end)."""
    def edge_point() -> np.ndarray:
        side, t = rng.integers(4), rng.uniform(-0.1, 1.1) * size
        return np.array([(t, -20), (size + 20, t), (t, size + 20), (-20, t)][side], np.float32)

    p0, p3 = edge_point(), edge_point()
    if rng.random() < 0.15:
        p3 = rng.uniform(0.2, 0.8, 2).astype(np.float32) * size
    bend = rng.uniform(0, 0.6) * size
    p1 = p0 + (p3 - p0) / 3 + rng.normal(0, 1, 2).astype(np.float32) * bend
    p2 = p0 + 2 * (p3 - p0) / 3 + rng.normal(0, 1, 2).astype(np.float32) * bend
    t = np.linspace(0, 1, 80, dtype=np.float32)[:, None]
    return ((1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * p1 + 3 * (1 - t) * t ** 2 * p2
            + t ** 3 * p3)


def _polyline(mask: np.ndarray, line: np.ndarray, width: float) -> None:
    """Draw ``line`` (float x, y) ``width`` px wide, anti-aliased, with 1/8 px precision."""
    pts = np.round(line * 8).astype(np.int32)
    cv2.polylines(mask, [pts], False, 1.0, max(1, round(width)), cv2.LINE_AA, shift=3)


def _surface(rng: np.random.Generator, ground: np.ndarray) -> np.ndarray:
    """A road's colour: asphalt (dark), concrete (light), or a dirt track (the ground's own
    hue, lighter and duller) — what the road is made of differs, its shape does not."""
    kind = rng.choice(3, p=[0.45, 0.2, 0.35])
    if kind == 0:
        return np.full(3, rng.uniform(0.22, 0.5), np.float32) * rng.uniform(0.95, 1.05, 3)
    if kind == 1:
        return np.full(3, rng.uniform(0.55, 0.8), np.float32) * rng.uniform(0.95, 1.05, 3)
    mean = ground.reshape(-1, 3).mean(axis=0)
    grey = float(mean.mean())
    return np.clip((grey + (mean - grey) * 0.5) * rng.uniform(1.15, 1.6), 0, 1)


def procedural_scene(rng: np.random.Generator, size: int, resolution_m: float = 0.5
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rgb float32 (size, size, 3) in [0, 1], road float32 (size, size), weight float32):
    one random scene (see module doc). Road pixels are where a road's surface covers at least
    half the pixel; every pixel counts in the loss."""
    m = 1 / resolution_m  # pixels per metre
    img = _ground(rng, size)
    road = np.zeros((size, size), np.float32)
    for _ in range(int(rng.integers(1, 5))):
        line = _curve(rng, size)
        width = rng.uniform(2.5, 14) * m
        mask = np.zeros_like(road)
        _polyline(mask, line, width)
        surface = _surface(rng, img)
        wear = 1 + 0.06 * _texture(rng, size, rng.uniform(0.5, 3))[..., None]
        img = img * (1 - mask[..., None]) + (surface * wear) * mask[..., None]
        if width > 5 * m and rng.random() < 0.5:  # painted centre or edge lines
            paint = np.zeros_like(road)
            dash = rng.random() < 0.5
            if dash:
                _polyline(paint, line, 0.15 * m)
                period = max(4, round(rng.uniform(6, 12) * m))
                paint *= (np.indices(paint.shape).sum(axis=0) // period % 2).astype(np.float32)
            else:
                for side in (-1, 1):
                    d = np.gradient(line, axis=0)
                    n = np.column_stack([-d[:, 1], d[:, 0]])
                    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-6
                    _polyline(paint, line + side * n * (width / 2 - 0.4 * m), 0.15 * m)
            colour = np.array((0.9, 0.85, 0.3) if rng.random() < 0.3 else (0.92,) * 3,
                              np.float32)
            img = img + (colour - img) * (paint * mask)[..., None]
        road = np.maximum(road, mask)
    if rng.random() < 0.3:  # a winding dry river bed: a dark or sandy band, not a road
        line = _curve(rng, size)
        line += rng.normal(0, 1, line.shape).cumsum(axis=0).astype(np.float32) * 0.6
        bed = np.zeros_like(road)
        _polyline(bed, line, rng.uniform(1.5, 6) * m)
        tone = rng.uniform(0.5, 1.3)
        img = img * (1 - bed[..., None]) + img * tone * bed[..., None]
    settled = rng.random() < 0.6  # a village or town; else open country
    for _ in range(int(rng.integers(0, 25 if settled else 3))):  # houses and their shadows
        centre = rng.uniform(0, size, 2)
        dims = rng.uniform(6, 20, 2) * m
        box = cv2.boxPoints(((float(centre[0]), float(centre[1])),
                             (float(dims[0]), float(dims[1])), float(rng.uniform(0, 90))))
        shadow = np.zeros_like(road)
        cv2.fillPoly(shadow, [np.round(box + 0.15 * dims.mean()).astype(np.int32)], 1.0)
        roof = np.zeros_like(road)
        cv2.fillPoly(roof, [np.round(box).astype(np.int32)], 1.0)
        if (roof * road).any():  # houses stand beside roads, not on them
            continue
        img = img * (1 - 0.45 * shadow[..., None])
        colour = ROOFS[rng.integers(len(ROOFS))] * rng.uniform(0.85, 1.15)
        img = img * (1 - roof[..., None]) + colour * roof[..., None]
    for _ in range(int(rng.integers(0, 40 if settled else 80))):  # tree crowns, over anything
        cx, cy = (int(v) for v in rng.uniform(0, size, 2))
        crown = np.zeros_like(road)
        cv2.circle(crown, (cx, cy), max(1, round(rng.uniform(1, 4) * m)), 1.0, cv2.FILLED,
                   cv2.LINE_AA)
        green = np.array((0.12, 0.22, 0.08), np.float32) * rng.uniform(0.7, 1.4)
        img = img * (1 - crown[..., None]) + green * crown[..., None]
    for _ in range(int(rng.integers(0, 4))):  # hairlines: fences, walls, field edges
        hair = np.zeros_like(road)
        _polyline(hair, _curve(rng, size), 1)
        img = img * (1 - 0.3 * hair[..., None])
    img += rng.normal(0, rng.uniform(0.005, 0.03), img.shape).astype(np.float32)
    labels = (road >= 0.5).astype(np.float32)
    return np.clip(img, 0, 1).astype(np.float32), labels, np.ones_like(labels)
