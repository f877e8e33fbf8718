"""A synthetic drive with known truth through the real ``ugvmap ingest ipm``, read back as
the XYZ tiles the app serves.

The drive (:mod:`ingest.ipm.synthetic`) is a right-hand bend on textured ground with coloured
markers at known lon/lat, seen by a tilted, offset panoramic camera above a red car roof
(masked), with frame times between the 20 Hz pose samples. The served tiles must place every
marker within one ground pixel (0.06 m) and match the ground texture (NCC > 0.9 after a light
blur) wherever covered; interpolating poses by nearest sample, or a wrong axis convention,
must fail the same check.
"""

from __future__ import annotations

import json
import uuid
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from click.testing import CliRunner
from pyproj import Transformer
from scipy.ndimage import label

from cli.main import main
from ingest.ipm.job import IpmOptions, ingest_ipm
from ingest.ipm.poses import Pose, PoseTrack
from ingest.ipm.synthetic import MARKER_RGB, Camera, Drive
from testkit.raster_synth import TMS, grid_transform, stitch

DRIVE, CAMERA = Drive(), Camera()
N_FRAMES = 36
RESOLUTION = 0.06
GRID_ARGS = ["--window", "20", "--zone-size", "512x512", "--zone-overlap", "32x32"]
OPTIONS = IpmOptions(window_m=20, zone_size_px=(512, 512), overlap_px=(32, 32))


@dataclass
class Check:
    ncc: float
    marker_errors_m: list[float]
    covered_px: int

    @property
    def passes(self) -> bool:
        return self.ncc > 0.9 and max(self.marker_errors_m) <= RESOLUTION


def grey(rgb: np.ndarray) -> np.ndarray:
    return cv2.GaussianBlur(rgb.astype(np.float32) @ np.float32([0.299, 0.587, 0.114]),
                            (0, 0), 1.5)


def check_layer(client, slug: str) -> Check:
    """Compare the served tiles of ``slug`` at its native zoom with the drive's truth."""
    info = client.get(f"/layers/{slug}").json()
    zoom = info["maxzoom"]
    west, south, east, north = info["bounds"]
    nw, se = TMS.tile(west, north, zoom), TMS.tile(east, south, zoom)
    block = (nw.x, nw.y, se.x - nw.x + 1, se.y - nw.y + 1)
    img = stitch(client.get, slug, zoom, block)
    transform = grid_transform(zoom, nw.x, nw.y)
    to_lonlat = Transformer.from_crs("EPSG:3857", "EPSG:4326", always_xy=True)
    opaque = img[..., 3] == 255
    rows, cols = np.nonzero(opaque)
    truth = np.zeros((*img.shape[:2], 3), np.float32)  # transparent pixels are black too
    for off in (0.25, 0.75):  # 2 x 2 samples per pixel, like the camera's anti-aliasing
        for off_r in (0.25, 0.75):
            lon, lat = to_lonlat.transform(transform.c + (cols + off) * transform.a,
                                           transform.f + (rows + off_r) * transform.e)
            truth[rows, cols] += DRIVE.texture(*DRIVE.to_local(lon, lat)) / 4
    # Blurring mixes in the black surround: compare only pixels well inside the coverage.
    covered = cv2.erode(opaque.astype(np.uint8), np.ones((11, 11), np.uint8)) > 0
    a, b = grey(img[..., :3])[covered], grey(truth)[covered]
    a, b = a - a.mean(), b - b.mean()
    ncc = float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))
    # Ground metres per tile pixel at this latitude.
    pixel_m = transform.a * np.cos(np.radians((south + north) / 2))
    to_3857 = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)
    errors = []
    for colour, lon, lat in DRIVE.marker_lonlats():
        x, y = to_3857.transform(lon, lat)
        col, row = ~transform @ (x, y)
        dist = np.linalg.norm(img[..., :3].astype(float) - MARKER_RGB[colour], axis=-1)
        blobs, _ = label((dist < 90) & opaque)
        near = 40  # px: look 2 m around the truth
        window = blobs[max(0, int(row) - near):int(row) + near,
                       max(0, int(col) - near):int(col) + near]
        ids = [i for i in np.unique(window) if i]
        if not ids:
            errors.append(np.inf)
            continue
        best = np.inf
        for i in ids:
            r, c = np.nonzero(blobs == i)
            best = min(best, float(np.hypot(c.mean() + 0.5 - col, r.mean() + 0.5 - row)))
        errors.append(best * pixel_m)
    return Check(ncc, errors, int(covered.sum()))


def test_synthetic_drive_through_the_cli_matches_the_truth(client, drive: dict[str, Path],
                                                            tmp_path: Path) -> None:
    slug = f"ipm-{uuid.uuid4().hex[:8]}"
    zones = tmp_path / "zones"
    result = CliRunner().invoke(main, [
        "ingest", "ipm", str(drive["frames"]), "--poses", str(drive["poses"]),
        "--calib", str(drive["calib"]), "--layer", slug, *GRID_ARGS, "--workers", "2",
        "--zones-dir", str(zones)])
    assert result.exit_code == 0, result.output
    assert f"frames: {N_FRAMES} used, 0 skipped" in result.output
    assert f"layer {slug} at version 1" in result.output

    check = check_layer(client, slug)
    assert check.covered_px > 100_000
    assert max(check.marker_errors_m) <= RESOLUTION, check.marker_errors_m
    assert check.ncc > 0.9, check.ncc

    info = client.get(f"/layers/{slug}").json()
    assert info["kind"] == "ipm-mosaic"
    kept = sorted(zones.glob("zone_*.tif"))
    assert len(info["sources"]) == len(kept) > 1
    assert all(s["georef"] == "zone" for s in info["sources"])
    sidecar = json.loads(kept[0].with_name(kept[0].name + ".zone.json").read_text())
    assert sidecar["zone_size_px"] == [512, 512] and sidecar["resolution_m"] == RESOLUTION
    jobs = client.get("/jobs", params={"limit": 50}).json()
    job = next(j for j in jobs["jobs"] if j["target"] == slug)
    assert job["kind"] == "ingest-ipm" and job["status"] == "succeeded"


def nearest_pose(track: PoseTrack, times: np.ndarray, max_gap_s: float) -> list[Pose | str]:
    """The mistake to rule out: each frame takes the pose sample nearest in time."""
    nearest = np.abs(track.t[None, :] - np.asarray(times)[:, None]).argmin(axis=1)
    return [Pose(float(t), float(track.lon[i]), float(track.lat[i]),
                 float(track.heading_deg[i])) for t, i in zip(times, nearest, strict=True)]


def test_the_check_fails_with_interpolation_or_axis_mistakes(client, drive: dict[str, Path],
                                                              tmp_path: Path) -> None:
    rotation = CAMERA.vehicle_from_camera().T  # the right d_cam = R · d_vehicle
    calib = json.loads(drive["calib"].read_text())
    angles = {k: calib.pop(k) for k in ("pitch_deg", "roll_deg", "yaw_deg")}
    variants = {
        "right (rotation matrix form)": ({"rotation": rotation.tolist()}, None),
        "nearest pose": ({"rotation": rotation.tolist()}, nearest_pose),
        "transposed rotation": ({"rotation": rotation.T.tolist()}, None),
        "yaw counter-clockwise": ({**angles, "yaw_deg": -angles["yaw_deg"]}, None),
    }
    results = {}
    for name, (rotation_doc, lookup) in variants.items():
        path = drive["calib"].with_name(f"calib-{uuid.uuid4().hex[:6]}.json")
        path.write_text(json.dumps({**calib, **rotation_doc}))
        slug = f"ipm-{uuid.uuid4().hex[:8]}"
        extra = {"pose_lookup": lookup} if lookup else {}
        ingest_ipm(drive["frames"], slug, path, drive["poses"], options=OPTIONS, **extra)
        results[name] = check_layer(client, slug)
    assert results["right (rotation matrix form)"].passes, results
    for name in ("nearest pose", "transposed rotation", "yaw counter-clockwise"):
        assert not results[name].passes, (name, results[name])
