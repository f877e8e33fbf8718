"""IPM geometry without a database: panorama model, calibration, lookup, poses, grid."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from pyproj import Geod, Transformer
from scipy.spatial.transform import Rotation

from ingest.ipm import IpmInputError
from ingest.ipm.calibration import (
    Calibration,
    ground_to_pixel,
    load_calibration,
    pixel_to_ground,
    rotation_from_angles,
)
from ingest.ipm.grid import GridPose, ZoneGrid
from ingest.ipm.lookup import build_lookup, sample_patch
from ingest.ipm.panorama import direction_to_pixel, pixel_to_direction
from ingest.ipm.place import place
from ingest.ipm.poses import NO_POSE, POSE_GAP, Pose, interpolate_poses, read_poses

SIZE = (1024, 512)
CALIBS = [
    Calibration(SIZE, np.array([0.0, 0.0, 2.5]), np.eye(3)),
    Calibration(SIZE, np.array([0.3, -0.8, 2.1]), rotation_from_angles(5.0, -4.0, 12.0)),
    Calibration(SIZE, np.array([-0.2, 1.1, 3.0]), rotation_from_angles(-8.0, 6.0, -170.0)),
]


def test_panorama_model_is_the_contract() -> None:
    w, h = SIZE
    cases = {(0, 1, 0): (w / 2, h / 2), (1, 0, 0): (3 * w / 4, h / 2),
             (-1, 0, 0): (w / 4, h / 2), (0, 0, 1): (None, 0), (0, 1, -1): (w / 2, 3 * h / 4)}
    for d, (u_want, v_want) in cases.items():
        u, v = direction_to_pixel(np.array(d, float), SIZE)
        assert v == pytest.approx(v_want)
        if u_want is not None:
            assert u == pytest.approx(u_want)
    # The centre of pixel (0, 0) is at +0.5: looking almost straight up and back.
    d = pixel_to_direction(0.5, 0.5, SIZE)
    assert d[2] == pytest.approx(math.cos(math.pi * 0.5 / h))
    assert math.degrees(math.atan2(d[0], d[1])) == pytest.approx(-180 + 180 * 0.5 / (w / 2))


@pytest.mark.parametrize("calib", CALIBS)
def test_ground_to_panorama_to_ground_round_trip(calib: Calibration) -> None:
    rng = np.random.default_rng(1)
    xy = rng.uniform(-30, 30, (20_000, 2))
    # Not straight under the camera (the nadir has no azimuth).
    xy = xy[np.hypot(*(xy - calib.camera_position_m[:2]).T) > 0.05]
    u, v = ground_to_pixel(xy, calib)
    assert np.abs(pixel_to_ground(u, v, calib) - xy).max() < 1e-6
    # And panorama -> ground -> panorama for pixels that see the ground.
    pu, pv = rng.uniform(0, SIZE[0], 5000), rng.uniform(0, SIZE[1], 5000)
    ground = pixel_to_ground(pu, pv, calib)
    hit = np.isfinite(ground[:, 0]) & (np.hypot(*(ground - calib.camera_position_m[:2]).T)
                                       < 1000)
    assert hit.sum() > 1000
    u2, v2 = ground_to_pixel(ground[hit], calib)
    du = (u2 - pu[hit] + SIZE[0] / 2) % SIZE[0] - SIZE[0] / 2
    assert np.abs(du).max() < 1e-6 and np.abs(v2 - pv[hit]).max() < 1e-6
    # Above the horizon nothing meets the ground.
    assert np.isnan(pixel_to_ground(np.array([10.0]), np.array([1.0]), CALIBS[0])).all()


def test_angle_order_and_signs() -> None:
    def pixel(rot: np.ndarray, d) -> tuple[float, float]:
        return direction_to_pixel(rot @ np.array(d, float), SIZE)

    w, h = SIZE
    # yaw +90: the camera's forward looks at the vehicle's right.
    assert pixel(rotation_from_angles(yaw_deg=90), (1, 0, 0))[0] == pytest.approx(w / 2)
    # pitch up: the vehicle's level forward direction appears below the camera's equator.
    assert pixel(rotation_from_angles(pitch_deg=10), (0, 1, 0))[1] > h / 2
    # roll right side down: the vehicle's level right appears above the equator.
    assert pixel(rotation_from_angles(roll_deg=10), (1, 0, 0))[1] < h / 2
    # The documented order, checked against SciPy's intrinsic Euler angles.
    for pitch, roll, yaw in [(5, -4, 12), (-30, 20, 100), (0, 45, -60)]:
        m = Rotation.from_euler("ZXY", [-yaw, pitch, roll], degrees=True).as_matrix()
        assert np.allclose(rotation_from_angles(pitch, roll, yaw), m.T, atol=1e-12)


def write(path: Path, doc: dict) -> Path:
    path.write_text(json.dumps(doc))
    return path


def test_calibration_files(tmp_path: Path) -> None:
    base = {"image_size": [1024, 512], "camera_position_m": [0.1, 0.2, 2.4]}
    rot = rotation_from_angles(3, -2, 5)
    a = load_calibration(write(tmp_path / "a.json", {**base, "rotation": rot.tolist()}))
    b = load_calibration(write(tmp_path / "b.json", {**base, "pitch_deg": 3, "roll_deg": -2,
                                                     "yaw_deg": 5}))
    assert np.allclose(a.rotation, b.rotation) and a.vehicle_mask is None
    mask = np.zeros((512, 1024), np.uint8)
    mask[400:] = 255
    cv2.imwrite(str(tmp_path / "mask.png"), mask)
    c = load_calibration(write(tmp_path / "c.json", {**base, "yaw_deg": 0,
                                                     "vehicle_mask": "mask.png"}))
    assert c.vehicle_mask is not None and c.vehicle_mask[450].all() and not c.vehicle_mask[0].any()

    bad = {
        "below the ground": {**base, "camera_position_m": [0, 0, -1.5], "yaw_deg": 0},
        "on or below": {**base, "camera_position_m": [0, 0, 0], "yaw_deg": 0},
        "not both": {**base, "rotation": rot.tolist(), "yaw_deg": 3},
        "not a rotation": {**base, "rotation": (rot * 2).tolist()},
        "equirectangular": {**base, "image_size": [1000, 600], "yaw_deg": 0},
        "no rotation": base,
        "3 numbers": {**base, "camera_position_m": [1, 2], "yaw_deg": 0},
        "vehicle_mask is 1024x512": {**base, "image_size": [2048, 1024], "yaw_deg": 0,
                                     "vehicle_mask": "mask.png"},
        "missing or not an image": {**base, "yaw_deg": 0, "vehicle_mask": "nope.png"},
    }
    for words, doc in bad.items():
        with pytest.raises(IpmInputError, match=words) as err:
            load_calibration(write(tmp_path / "bad.json", doc))
        assert "\n" not in str(err.value)
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(IpmInputError, match="cannot read"):
        load_calibration(tmp_path / "junk.json")


def test_lookup_samples_where_the_model_says(tmp_path: Path) -> None:
    """A smooth, azimuth-periodic panorama sampled through the lookup equals the same function
    at the modelled pixel: no half-pixel shift, and the seam behind the camera wraps."""
    calib = CALIBS[1]
    w, h = SIZE

    def f(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return 120 + 60 * np.sin(2 * np.pi * 8 * u / w) + 0.2 * v

    cols, rows = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    pano = f(cols, rows).astype(np.float32)[..., None].repeat(3, axis=2)
    lookup = build_lookup(calib, 24.0, 0.06, 12.0)
    patch = sample_patch(pano, lookup)
    valid = patch[..., 3] == 255
    u, v = ground_to_pixel(lookup.window.cell_centres(), calib)
    err = np.abs(patch[..., 0] - f(u, v))[valid]
    assert valid.mean() > 0.6
    assert err.max() < 0.6, err.max()
    # The window covers the seam (azimuth ±180°) behind the camera.
    assert ((u[valid] < 2) | (u[valid] > w - 2)).any()


def test_lookup_masks_range_and_car(tmp_path: Path) -> None:
    mask = np.zeros((512, 1024), bool)
    mask[430:] = True  # the car below ~ 61° from straight down
    calib = Calibration(SIZE, np.array([0.0, 0.0, 2.0]), np.eye(3), mask)
    lookup = build_lookup(calib, 30.0, 0.1, 10.0)
    xy = lookup.window.cell_centres()
    r = np.hypot(xy[..., 0], xy[..., 1])
    valid = lookup.valid == 255
    assert not valid[r > 10].any()
    # v = 430 px is 151.2° from up: ground within 2 * tan(28.8°) = 1.1 m is car.
    assert not valid[r < 1.0].any() and valid[(r > 1.5) & (r < 9.5)].all()
    with pytest.raises(IpmInputError, match="--window"):
        build_lookup(calib, 0.2, 0.06, 10)


def test_pose_stream(tmp_path: Path) -> None:
    path = tmp_path / "poses.csv"
    path.write_text("t,lon,lat,heading_deg,alt,pitch_deg\n"
                    "0.0,10.0,50.0,358.0,100,1\n1.0,10.0002,50.0001,2.0,100,1\n"
                    "3.0,10.0004,50.0002,10.0,100,1\n")
    track = read_poses(path)
    poses = interpolate_poses(track, np.array([0.5, 0.25, 2.0, -1, 3.5, 1.0]), max_gap_s=1.5)
    mid = poses[0]
    assert isinstance(mid, Pose)
    assert (mid.lon, mid.lat) == pytest.approx((10.0001, 50.00005), abs=1e-12)
    assert mid.heading_deg == pytest.approx(0.0, abs=1e-9)  # the short way round, not 180
    assert poses[1].heading_deg == pytest.approx(359.0)
    assert poses[2] == POSE_GAP and poses[3] == NO_POSE and poses[4] == NO_POSE
    assert poses[5].lon == pytest.approx(10.0002)
    assert isinstance(interpolate_poses(track, np.array([2.0]), 2.5)[0], Pose)

    cases = {"not after the previous": "t,lon,lat,heading_deg\n0,1,1,0\n2,1,1,0\n1,1,1,0\n",
             "line 3: time 0.0 is not after": "t,lon,lat,heading_deg\n0,1,1,0\n0,1,1,0\n",
             "missing column": "t,lon,lat\n0,1,1\n1,1,1\n",
             "not all numbers": "t,lon,lat,heading_deg\n0,1,x,0\n1,1,1,0\n",
             "WGS84": "t,lon,lat,heading_deg\n0,500000,4000000,0\n1,1,1,0\n",
             "at least two": "t,lon,lat,heading_deg\n0,1,1,0\n"}
    for words, text in cases.items():
        path.write_text(text)
        with pytest.raises(IpmInputError, match=words) as err:
            read_poses(path)
        assert "\n" not in str(err.value)


def test_grid_poses_use_grid_north_and_scale() -> None:
    grid = ZoneGrid(17.6, 48.15)
    lon, lat = 17.61, 48.16
    pose = grid.to_grid([lon], [lat], [0.0])[0]
    # True north's bearing on the grid, by finite differences in the zone's UTM.
    utm = Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True)
    e1, n1 = utm.transform(lon, lat - 1e-5)
    e2, n2 = utm.transform(lon, lat + 1e-5)
    assert pose.bearing == pytest.approx(math.atan2(e2 - e1, n2 - n1), abs=1e-7)
    assert math.degrees(pose.bearing) == pytest.approx(-1.95, abs=0.05)
    # Grid metres per ground metre: the same step on the grid and on the ellipsoid.
    ground = Geod(ellps="WGS84").inv(lon, lat - 1e-5, lon, lat + 1e-5)[2]
    assert pose.scale == pytest.approx(math.hypot(e2 - e1, n2 - n1) / ground, abs=1e-8)
    assert pose.scale > 1.00005  # 2.6° from the central meridian: UTM stretches
    origin = grid.to_grid([17.6], [48.15], [90.0])[0]
    assert (origin.col, origin.row) == pytest.approx((0.0, 0.0), abs=1e-6)
    east, north = utm.transform(lon, lat)
    east0, north0 = utm.transform(17.6, 48.15)
    assert pose.col == pytest.approx((east - east0) / 0.06)
    assert pose.row == pytest.approx((north0 - north) / 0.06)


def test_default_grid_is_centred_on_the_first_pose() -> None:
    grid = ZoneGrid.centred_on(17.6, 48.15, 0.06, (4096, 4096), (128, 128))
    pose = grid.to_grid([17.6], [48.15], [0.0])[0]
    assert (pose.col, pose.row) == pytest.approx((3968 / 2, 3968 / 2), abs=1e-6)
    assert grid.sidecar(0, 0).crs().to_epsg() == 32633


def test_zones_meeting_a_box() -> None:
    grid = ZoneGrid(17.6, 48.15, zone_size_px=(100, 60), overlap_px=(20, 10))
    for box in [(0, 0, 1, 1), (79, 49, 81, 51), (-5, -5, 5, 5), (150, 30, 420, 200),
                (80, 50, 100, 60)]:
        want = {(r, c) for r in range(-3, 10) for c in range(-3, 10)
                if c * 80 < box[2] and c * 80 + 100 > box[0]
                and r * 50 < box[3] and r * 50 + 60 > box[1]}
        assert set(grid.zones_meeting(*box)) == want, box


def test_place_rotates_by_heading_and_moves_by_position() -> None:
    calib = Calibration(SIZE, np.array([0.0, 0.0, 2.0]), np.eye(3))
    lookup = build_lookup(calib, 12.0, 0.1, 100.0)
    n = lookup.window.size_px
    patch = np.zeros((n, n, 4), np.uint8)
    patch[..., 3] = 255
    # A bright cell 4 m ahead of the camera (row 60 - 40 = 20, column 60).
    patch[19:21, 59:61, :3] = 255
    for heading, (dc, dr) in {0.0: (0, -40), 90.0: (40, 0), 180.0: (0, 40),
                              -45.0: (-40 / math.sqrt(2), -40 / math.sqrt(2))}.items():
        pose = GridPose(1000.0, 2000.0, math.radians(heading), 1.0)
        placed = place(patch, lookup.window, pose, 0.1)
        weight = placed.colour[..., 0].astype(float)
        r, c = np.mgrid[0:weight.shape[0], 0:weight.shape[1]] + 0.5
        col = placed.col0 + (weight * c).sum() / weight.sum()
        row = placed.row0 + (weight * r).sum() / weight.sum()
        assert (col, row) == pytest.approx((1000 + dc, 2000 + dr), abs=0.05), heading
        # Distances are measured from the camera (at the pose here), per pixel centre.
        i, j = 7, 11
        want = (placed.col0 + j + 0.5 - 1000) ** 2 + (placed.row0 + i + 0.5 - 2000) ** 2
        assert placed.dist2[i, j] == pytest.approx(want)
