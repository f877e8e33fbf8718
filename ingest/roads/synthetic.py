"""Synthetic aerial scenes with known roads, for unit tests, benchmarks and demos.

A scene is textured vegetation with grey asphalt polylines drawn at a known width, optional
grey house roofs (the same colour as the road, the classic false positive) and hairline
scratches off the roads. Because the drawn centerlines are known exactly, every stage of the
pipeline can be checked against them. :func:`ipm_scene` is a vehicle's own drive instead: a
fine top-down mosaic with a coverage mask and the trajectory as the sample.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
import shapely
from rasterio.crs import CRS
from rasterio.features import rasterize
from rasterio.transform import Affine

from app.road_tuning import DEFAULT_SAMPLE_WIDTH
from ingest.ipm.synthetic import Drive
from ingest.roads.georef import Image
from ingest.roads.sample import GeoSample, sample_labels

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
    road_rgb: tuple[int, int, int] = ROAD_RGB
    ground_rgb: tuple[int, int, int] = GRASS_RGB
    decoys: list[Polyline] = field(default_factory=list)
    """Road-like strips that are not roads (canals, field edges), drawn road-width in
    ``decoy_rgb``: what a map team teaches the model to leave out."""
    decoy_rgb: tuple[int, int, int] = ROAD_RGB


def render(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(rgb uint8 image, boolean road-surface mask) of a scene."""
    rng = np.random.default_rng(scene.seed)
    rows, cols = scene.shape
    noise = rng.normal(0, 1, (rows, cols)).astype(np.float32)
    texture: np.ndarray = cv2.GaussianBlur(noise, (0, 0), 3)
    texture /= texture.std() + 1e-6
    img = np.empty((rows, cols, 3), np.float32)
    img[:] = scene.ground_rgb
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
    decoys = np.zeros_like(road)
    for line in scene.decoys:
        cv2.polylines(decoys, [np.asarray(line, np.int32)], False, 1, scene.road_width_px)
    for mask, rgb in ((decoys.astype(bool) & ~road.astype(bool), scene.decoy_rgb),
                      ((road | roofs).astype(bool), scene.road_rgb)):
        wear = 1.0 + 0.12 * np.clip(texture[mask], -2.5, 2.5)
        img[mask] = np.outer(wear, rgb)
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


@dataclass(frozen=True)
class IpmScene:
    """A top-down mosaic of a drive, its coverage and truth."""

    image: Image
    labels: np.ndarray
    coverage: np.ndarray
    transform: Affine
    centre_radius_m: float

    def truth_distance(self, pts: np.ndarray) -> np.ndarray:
        """Distance (m) of local (east, north) points to the true centreline (the ring's road
        exists all round; the drive saw only part of it)."""
        return np.abs(np.hypot(pts[:, 0], pts[:, 1]) - self.centre_radius_m)


def ipm_scene(resolution_m: float = 0.06, sweep_deg: float = 320.0,
              swath_m: float = 9.0) -> IpmScene:
    """A 0.06 m top-down mosaic of :class:`ingest.ipm.synthetic.Drive`'s road (7 m wide, edge
    lines, dashed centre line) along ``sweep_deg`` of its ring, seen only within ``swath_m``
    of the vehicle's path (no-data elsewhere, so the rest of the ring is unseen), with the
    trajectory burnt as the road sample the way ``ingest roads`` burns ``--train-lines``."""
    drive = Drive()
    length = math.radians(sweep_deg) * drive.radius_m
    east, north, _ = drive.local_pose(np.arange(0.0, length + 0.25, 0.25))
    path = shapely.LineString(np.column_stack([east, north]))
    x0, y0, x1, y1 = path.buffer(swath_m + 1).bounds
    cols, rows = math.ceil((x1 - x0) / resolution_m), math.ceil((y1 - y0) / resolution_m)
    transform = Affine.translation(x0, y1) @ Affine.scale(resolution_m, -resolution_m)
    coverage = rasterize([(path.buffer(swath_m), 1)], out_shape=(rows, cols),
                         transform=transform).astype(bool)
    rgb = np.zeros((rows, cols, 3), np.float32)
    r, c = np.nonzero(coverage)
    for dr in (0.25, 0.75):  # 2 x 2 samples per pixel, as a camera integrates
        for dc in (0.25, 0.75):
            e, n = transform @ (c + dc, r + dr)
            rgb[r, c] += drive.texture(e, n) / 4
    crs = CRS.from_proj4(f"+proj=aeqd +lat_0={drive.lat0} +lon_0={drive.lon0} +ellps=WGS84 "
                         "+units=m")
    lon, lat = drive.to_lonlat(east, north)
    sample = GeoSample(road_lines=[shapely.LineString(np.column_stack([lon, lat]))],
                       not_road_beyond_m=3 * DEFAULT_SAMPLE_WIDTH.line_width)
    labels = sample_labels((rows, cols), transform, crs, sample)
    image = Image(rgb / 255, coverage, transform, crs, resolution_m)
    return IpmScene(image, labels, coverage, transform, drive.radius_m + drive.road_offset_m)
