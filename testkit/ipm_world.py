"""Panorama drives rendered with conventions of their own, to check the drive path on imagery
``ingest.ipm.synthetic`` did not make.

``ingest.ipm.synthetic`` and the pipeline were written together; a bias that suits both (a
road width, the vehicle's lane, a texture, a camera mount) would pass every test made with it.
This renderer shares nothing with either but the documented contract (the calibration JSON,
the equirectangular pixel model, ``poses.csv`` / ``frames.csv``): the road is a circle around
a centre in a *transverse Mercator* frame (not the renderer's azimuthal one, not UTM), the
camera's rotation is written as a matrix built by Rodrigues' formula about an arbitrary axis
(not Euler angles), headings come from geodesic azimuths (not a frame's grid bearing), the
ground is an orthophoto drawn once and sampled per ray (not a texture function), with random
noise rather than sinusoids, and the vehicle may drive anywhere across the road and change
lanes while it drives.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from pyproj import Geod, Transformer

GEOD = Geod(ellps="WGS84")
MARKER_RGB = ((220, 30, 30), (30, 70, 220), (230, 200, 20))
MARKER_RADIUS_M = 0.25


def rodrigues(axis: tuple[float, float, float], angle_deg: float) -> np.ndarray:
    """The rotation by ``angle_deg`` about ``axis`` (right-handed), as a 3x3 matrix."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = math.radians(angle_deg)
    return np.eye(3) + math.sin(a) * cross + (1 - math.cos(a)) * cross @ cross


@dataclass(frozen=True)
class Mount:
    """The camera: where it sits (vehicle frame x right, y forward, z up), how it is turned
    (camera axes = vehicle axes rotated by ``tilt_deg`` about ``tilt_axis``), the panorama
    size, and the roof it looks over (masked)."""

    position_m: tuple[float, float, float] = (0.0, -0.4, 1.9)
    tilt_axis: tuple[float, float, float] = (0.4, 1.0, 0.2)
    tilt_deg: float = 6.0
    size: tuple[int, int] = (1024, 512)
    roof_z_m: float = 1.35
    roof_m: tuple[float, float, float, float] = (-0.85, -1.9, 0.85, 0.6)

    def vehicle_from_camera(self) -> np.ndarray:
        """d_vehicle = M · d_cam."""
        return rodrigues(self.tilt_axis, self.tilt_deg)

    def rays(self, du: float, dv: float) -> np.ndarray:
        """(H, W, 3) vehicle-frame unit rays through pixel offset (du, dv) of each pixel."""
        width, height = self.size
        u = np.arange(width) + du
        v = np.arange(height) + dv
        az = (u / width) * 2 * np.pi - np.pi          # 0 at the image centre: forward
        polar = v * (np.pi / height)                   # 0 at the top row: up
        s = np.sin(polar)[:, None]
        cam = np.stack(np.broadcast_arrays(s * np.sin(az)[None, :], s * np.cos(az)[None, :],
                                           np.cos(polar)[:, None]), axis=-1)
        return cam @ self.vehicle_from_camera().T

    def on_roof(self, rays: np.ndarray) -> np.ndarray:
        """Rays that meet the roof rectangle."""
        x0, y0, z0 = self.position_m
        dz = rays[..., 2]
        t = np.where(dz < 0, (self.roof_z_m - z0) / np.where(dz < 0, dz, -1), -1)
        x, y = x0 + t * rays[..., 0], y0 + t * rays[..., 1]
        a, b, c, d = self.roof_m
        return (t > 0) & (x >= a) & (x <= c) & (y >= b) & (y <= d)

    def calibration(self) -> dict:
        """The calibration document (``rotation`` as a matrix: d_cam = R · d_vehicle)."""
        return {"image_size": list(self.size), "camera_position_m": list(self.position_m),
                "rotation": self.vehicle_from_camera().T.tolist(), "vehicle_mask": "body.png"}


@dataclass(frozen=True)
class Look:
    """Colours: road and ground (mean RGB and noise), and the paint."""

    road_rgb: tuple[float, float, float] = (118, 118, 122)
    road_noise: float = 9.0
    ground_rgb: tuple[float, float, float] = (78, 74, 66)
    ground_noise: float = 16.0
    paint_rgb: tuple[float, float, float] = (236, 236, 230)


@dataclass(frozen=True)
class World:
    """A circular road (centre ``radius_m`` from the circle's centre, ``width_m`` wide) driven
    ``arc_deg`` of the way round, clockwise (a right bend) or not, with the vehicle
    ``offset_m(s)`` right of the road's centre line: ``offsets_m[0]`` before ``change_at_m``
    along the road and ``offsets_m[1]`` after a ``change_len_m`` lane change."""

    lon0: float = 9.9
    lat0: float = 52.4
    radius_m: float = 60.0
    width_m: float = 7.0
    clockwise: bool = True
    arc_deg: float = 150.0
    speed_mps: float = 8.0
    offsets_m: tuple[float, float] = (0.0, 0.0)
    change_at_m: float = 60.0
    change_len_m: float = 25.0
    centre_dash_m: tuple[float, float] | None = (3.0, 5.0)
    """Dash and gap of the white centre line; None: no centre line."""
    edge_lines: bool = False
    line_width_m: float = 0.12
    marker_out_m: float = 2.2
    """Coloured discs this far outside each road edge, every 11 m; 0: none."""
    look: Look = field(default_factory=Look)
    ortho_m: float = 0.025
    seed: int = 3

    # --- geometry (local transverse Mercator metres; the circle's centre at the origin) ---

    def _tm(self) -> str:
        return (f"+proj=tmerc +lat_0={self.lat0} +lon_0={self.lon0} +k_0=1 +x_0=0 +y_0=0 "
                "+ellps=WGS84 +units=m")

    def lonlat(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Local metres -> WGS84."""
        return Transformer.from_crs(self._tm(), "EPSG:4326", always_xy=True).transform(x, y)

    def local(self, lon: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 -> local metres."""
        return Transformer.from_crs("EPSG:4326", self._tm(), always_xy=True).transform(lon, lat)

    @property
    def length_m(self) -> float:
        """Length of the driven stretch of the road's centre line."""
        return math.radians(self.arc_deg) * self.radius_m

    def offset_m(self, s: np.ndarray) -> np.ndarray:
        """The vehicle's distance right of the centre line after ``s`` metres along it."""
        a, b = self.offsets_m
        x = np.clip((np.asarray(s, float) - self.change_at_m) / self.change_len_m, 0, 1)
        return a + (b - a) * (3 * x**2 - 2 * x**3)

    def _angle(self, s: np.ndarray) -> np.ndarray:
        """Polar angle (from +x, anticlockwise) of the point ``s`` along the centre line; the
        drive starts at angle 200° (clockwise) or -20° (anticlockwise)."""
        turn = np.asarray(s, float) / self.radius_m
        return np.radians(200.0) - turn if self.clockwise else np.radians(-20.0) + turn

    def vehicle_xy(self, s: np.ndarray) -> np.ndarray:
        """(n, 2) vehicle positions after ``s`` metres along the road."""
        a = self._angle(s)
        # Right of the direction of travel is outwards on a clockwise circle.
        r = self.radius_m + (self.offset_m(s) if self.clockwise else -self.offset_m(s))
        return np.column_stack([r * np.cos(a), r * np.sin(a)])

    def signed_offset_m(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Distance of local points from the road's centre line (+ outside the circle)."""
        return np.hypot(x, y) - self.radius_m

    # --- the drive ---

    def poses(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(lon, lat, heading from true north, clockwise) of the vehicle at times ``t``."""
        s = np.asarray(t, float) * self.speed_mps
        here = self.vehicle_xy(s)
        ahead = self.vehicle_xy(s + 0.05)
        lon, lat = self.lonlat(here[:, 0], here[:, 1])
        lon2, lat2 = self.lonlat(ahead[:, 0], ahead[:, 1])
        azimuth, _, _ = GEOD.inv(lon, lat, lon2, lat2)
        return np.asarray(lon), np.asarray(lat), np.mod(azimuth, 360.0)

    def duration_s(self) -> float:
        """Seconds the drive takes."""
        return self.length_m / self.speed_mps

    def markers(self) -> np.ndarray:
        """(n, 2) local centres of the coloured discs: every 11 m along the road,
        ``marker_out_m`` outside its edges, alternately right and left (none when 0)."""
        if self.marker_out_m <= 0:
            return np.zeros((0, 2))
        s = np.arange(5.0, self.length_m, 11.0)
        side = np.where(np.arange(len(s)) % 2, 1.0, -1.0)
        r = self.radius_m + side * (self.width_m / 2 + self.marker_out_m)
        a = self._angle(s)
        return np.column_stack([r * np.cos(a), r * np.sin(a)])

    # --- the ground as an orthophoto ---

    def ortho(self, pad_m: float = 18.0) -> tuple[np.ndarray, float, float]:
        """(RGB float32 image, x of its left edge, y of its top edge) of the ground around the
        drive at ``ortho_m`` per pixel, north up."""
        path = self.vehicle_xy(np.linspace(0, self.length_m, 200))
        x0, y0 = path.min(axis=0) - pad_m
        x1, y1 = path.max(axis=0) + pad_m
        res = self.ortho_m
        cols, rows = int((x1 - x0) / res), int((y1 - y0) / res)
        rng = np.random.default_rng(self.seed)
        xs = x0 + (np.arange(cols) + 0.5) * res
        ys = y1 - (np.arange(rows) + 0.5) * res
        x, y = np.meshgrid(xs.astype(np.float32), ys.astype(np.float32))
        d = self.signed_offset_m(x, y)
        look = self.look

        def noisy(rgb: tuple[float, float, float], amount: float) -> np.ndarray:
            grain = cv2.GaussianBlur(rng.standard_normal((rows, cols)).astype(np.float32),
                                     (0, 0), 1.2) * (amount * 2.2)
            coarse = cv2.GaussianBlur(rng.standard_normal((rows // 8, cols // 8)).astype(
                np.float32), (0, 0), 6) * (amount * 8)
            patches = cv2.resize(coarse, (cols, rows), interpolation=cv2.INTER_LINEAR)
            return np.asarray(rgb, np.float32) + (grain + patches)[..., None]

        road = np.abs(d) <= self.width_m / 2
        img = np.where(road[..., None], noisy(look.road_rgb, look.road_noise),
                       noisy(look.ground_rgb, look.ground_noise))
        along = np.arctan2(y, x) * self.radius_m
        half = self.line_width_m / 2
        paint = np.zeros_like(road)
        if self.centre_dash_m is not None:
            dash, gap = self.centre_dash_m
            paint |= (np.abs(d) <= half) & (np.mod(along, dash + gap) < dash)
        if self.edge_lines:
            paint |= np.abs(np.abs(d) - (self.width_m / 2 - 0.25)) <= half
        img[paint] = look.paint_rgb
        for i, (mx, my) in enumerate(self.markers()):
            # OpenCV puts pixel centres on integers; this image's are at +0.5.
            cx, cy = (mx - x0) / res - 0.5, (y1 - my) / res - 0.5
            cv2.circle(img, (round(cx * 16), round(cy * 16)), round(MARKER_RADIUS_M / res * 16),
                       MARKER_RGB[i % 3], -1, cv2.LINE_AA, shift=4)
        return np.clip(img, 0, 255).astype(np.float32), float(x0), float(y1)


def render(world: World, mount: Mount, ortho: tuple[np.ndarray, float, float],
           t: float, supersample: int = 2) -> np.ndarray:
    """The BGR panorama the camera takes at time ``t``."""
    image, left, top = ortho
    res = world.ortho_m
    [(vx, vy)] = world.vehicle_xy(np.array([t * world.speed_mps]))
    # The pose stream's heading is from true north, which the local frame's grid north is
    # not (convergence): the vehicle is turned here by its direction of travel on the grid.
    [(ax, ay)] = world.vehicle_xy(np.array([t * world.speed_mps + 0.05]))
    fx, fy = (ax - vx), (ay - vy)
    n = math.hypot(fx, fy)
    fx, fy = fx / n, fy / n
    rx, ry = fy, -fx  # right of forward
    width, height = mount.size
    acc = np.zeros((height, width, 3), np.float32)
    steps = (np.arange(supersample) + 0.5) / supersample
    sky = np.array([200, 170, 120], np.float32)  # BGR
    roof = np.array([40, 40, 50], np.float32)
    cz = mount.position_m[2]
    for du in steps:
        for dv in steps:
            d = mount.rays(du, dv)
            down = d[..., 2] < -1e-6
            tt = np.where(down, cz / np.where(down, -d[..., 2], 1), 0)
            gx = mount.position_m[0] + tt * d[..., 0]
            gy = mount.position_m[1] + tt * d[..., 1]
            ex = vx + gx * rx + gy * fx
            ey = vy + gx * ry + gy * fy
            mx = ((ex - left) / res - 0.5).astype(np.float32)
            my = ((top - ey) / res - 0.5).astype(np.float32)
            ground = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            colour = np.where(down[..., None], ground[..., ::-1], sky)
            colour[mount.on_roof(d)] = roof
            acc += colour
    return np.clip(acc / supersample**2 + 0.5, 0, 255).astype(np.uint8)


def body_mask(mount: Mount) -> np.ndarray:
    """255 where any of 3x3 points of a pixel sees the roof."""
    width, height = mount.size
    mask = np.zeros((height, width), bool)
    for du in (0.0, 0.5, 1.0):
        for dv in (0.0, 0.5, 1.0):
            mask |= mount.on_roof(mount.rays(du, dv))
    return np.where(mask, 255, 0).astype(np.uint8)


def write(folder: Path, world: World, mount: Mount, frame_hz: float = 7.5,
          pose_hz: float = 10.0, frames: int | None = None) -> dict[str, Path]:
    """The drive's frames (JPEG + frames.csv), poses.csv, calib.json and body.png in
    ``folder``; ``frames`` limits the count (default: the whole arc)."""
    frames_dir = folder / "frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    duration = world.duration_s()
    times = np.arange(0.37, duration - 0.2, 1.0 / frame_hz)
    if frames is not None:
        times = times[:frames]
    ortho = world.ortho()
    with open(frames_dir / "frames.csv", "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["t", "file"])
        for i, t in enumerate(times):
            name = f"pano{i:04d}.jpg"
            cv2.imwrite(str(frames_dir / name), render(world, mount, ortho, float(t)),
                        [cv2.IMWRITE_JPEG_QUALITY, 92])
            out.writerow([f"{t:.5f}", name])
    pose_t = np.arange(0.0, float(times[-1]) + 0.5, 1.0 / pose_hz)
    lon, lat, heading = world.poses(pose_t)
    with open(folder / "poses.csv", "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["t", "lon", "lat", "heading_deg"])
        for row in zip(pose_t, lon, lat, heading, strict=True):
            out.writerow([f"{row[0]:.3f}", f"{row[1]:.9f}", f"{row[2]:.9f}", f"{row[3]:.4f}"])
    cv2.imwrite(str(folder / "body.png"), body_mask(mount))
    (folder / "calib.json").write_text(json.dumps(mount.calibration()))
    return {"frames": frames_dir, "poses": folder / "poses.csv",
            "calib": folder / "calib.json"}


#: Drives with other conventions than ``ingest.ipm.synthetic``'s (a 7 m road on green grass,
#: driven in its right lane by a 2.4 m camera): what ``bench/ipm_centreline.py`` measures.
VARIED: dict[str, tuple[World, Mount]] = {
    # The drive: grey road on darker, noisy grey ground (on the asphalt's colour
    # line), the vehicle on the dashed centre line, markers 2.2 m outside the road.
    "grey-ground": (World(look=Look(road_rgb=(125, 125, 125), road_noise=6,
                                    ground_rgb=(95, 95, 95), ground_noise=25)), Mount()),
    # A wide road, a left bend, edge lines; the vehicle changes from the right lane across
    # the centre line; a higher camera, turned about another axis; markers 3 m out.
    "wide-lane-change": (World(lon0=14.9, lat0=40.2, radius_m=45.0, width_m=10.5,
                               clockwise=False, arc_deg=120.0, offsets_m=(2.6, -1.2),
                               change_at_m=35.0, edge_lines=True, marker_out_m=3.0,
                               look=Look(ground_rgb=(92, 108, 70))),
                         Mount(position_m=(0.3, 0.5, 2.3), tilt_axis=(1.0, -0.3, 0.5),
                               tilt_deg=-5.0)),
    # A narrow light concrete lane on dark soil, no paint, the vehicle right of its centre,
    # a low camera and a coarser panorama.
    "narrow-concrete": (World(lon0=-3.7, lat0=40.4, radius_m=120.0, width_m=5.0,
                              arc_deg=50.0, offsets_m=(0.9, 0.9), centre_dash_m=None,
                              marker_out_m=1.0, seed=5,
                              look=Look(road_rgb=(168, 164, 155), road_noise=7,
                                        ground_rgb=(70, 58, 45), ground_noise=14)),
                        Mount(position_m=(0.0, 0.9, 1.6), tilt_axis=(0.0, 1.0, 0.0),
                              tilt_deg=3.0, size=(768, 384), roof_z_m=1.2,
                              roof_m=(-0.8, -1.5, 0.8, 0.7))),
    # Dark asphalt on a brighter grey gravel verge (on the line beyond the road's end), the
    # vehicle left of the centre line.
    "gravel-verge": (World(lon0=21.0, lat0=60.2, radius_m=80.0, width_m=6.0, arc_deg=75.0,
                           offsets_m=(-0.8, -0.8), centre_dash_m=(4.0, 4.0), seed=7,
                           look=Look(road_rgb=(88, 88, 92), road_noise=8,
                                     ground_rgb=(142, 140, 136), ground_noise=18)),
                     Mount(tilt_deg=-4.0)),
}
