"""Synthetic aerial scenes with known roads, for unit tests, benchmarks and demos.

A scene is textured vegetation with grey asphalt polylines drawn at a known width, optional
grey house roofs (the same colour as the road, the classic false positive) and hairline
scratches off the roads. Because the drawn centerlines are known exactly, every stage of the
pipeline can be checked against them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

Polyline = Sequence[tuple[int, int]]
ROAD_RGB = (118, 118, 122)
GRASS_RGB = (62, 118, 42)


@dataclass(frozen=True)
class Scene:
    """What to draw: (x, y) pixel polylines and circles, roofs as (x0, y0, x1, y1)."""

    shape: tuple[int, int]
    roads: list[Polyline] = field(default_factory=list)
    rings: list[tuple[tuple[int, int], int]] = field(default_factory=list)
    """Circular roads: ((cx, cy), radius)."""
    road_width_px: int = 12
    houses: list[tuple[int, int, int, int]] = field(default_factory=list)
    hairs: list[Polyline] = field(default_factory=list)
    noise: float = 6.0
    seed: int = 0


def render(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(rgb uint8 image, boolean road-surface mask) of a scene."""
    rng = np.random.default_rng(scene.seed)
    rows, cols = scene.shape
    noise = rng.normal(0, 1, (rows, cols)).astype(np.float32)
    texture: np.ndarray = cv2.GaussianBlur(noise, (0, 0), 3)
    texture /= texture.std() + 1e-6
    img = np.empty((rows, cols, 3), np.float32)
    img[:] = GRASS_RGB
    img += texture[..., None] * np.array([8, 14, 6], np.float32)
    road = np.zeros((rows, cols), np.uint8)
    for line in scene.roads:
        cv2.polylines(road, [np.asarray(line, np.int32)], False, 1, scene.road_width_px)
    for (cx, cy), radius in scene.rings:
        cv2.circle(road, (cx, cy), radius, 1, scene.road_width_px)
    roofs = np.zeros_like(road)
    for x0, y0, x1, y1 in scene.houses:
        cv2.rectangle(roofs, (x0, y0), (x1, y1), 1, cv2.FILLED)
    for line in scene.hairs:
        cv2.polylines(roofs, [np.asarray(line, np.int32)], False, 1, 1)
    grey = (road | roofs).astype(bool)
    wear = 1.0 + 0.12 * np.clip(texture[grey], -2.5, 2.5)
    img[grey] = np.outer(wear, ROAD_RGB)
    img += rng.normal(0, scene.noise, img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8), road.astype(bool)


def grid_scene(size: int, spacing: int, road_width_px: int, seed: int = 0) -> Scene:
    """A town-like square grid of roads with a roof in every block (for benchmarks)."""
    lines: list[Polyline] = [[(x, 0), (x, size - 1)] for x in range(spacing // 2, size, spacing)]
    lines += [[(0, y), (size - 1, y)] for y in range(spacing // 2, size, spacing)]
    roof = spacing // 5
    houses = [(x + roof, y + roof, x + 2 * roof, y + 2 * roof)
              for x in range(spacing // 2, size - spacing, spacing)
              for y in range(spacing // 2, size - spacing, spacing)]
    return Scene((size, size), roads=lines, road_width_px=road_width_px, houses=houses,
                 seed=seed)
