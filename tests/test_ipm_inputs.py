"""``ugvmap ingest ipm`` with imperfect input: one-line errors that write nothing, or frames
skipped and counted while the rest of the drive is kept; video input and QR-stamped poses."""

from __future__ import annotations

import csv
import shutil
import uuid
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from cli.main import main
from ingest.ipm.frames import FrameError, decode_image
from ingest.ipm.poses import Pose
from ingest.ipm.qrpose import stamp_pose
from ingest.ipm.synthetic import Camera, Drive, frame_times, write_drive

CAMERA = Camera()
DRIVE = Drive()
N = 14
GRID = ["--window", "16", "--zone-size", "512x512", "--zone-overlap", "32x32"]


@pytest.fixture(scope="module")
def small(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return write_drive(tmp_path_factory.mktemp("small"), DRIVE, CAMERA, frame_times(N),
                       supersample=1)


@pytest.fixture()
def drive(small: dict[str, Path], tmp_path: Path) -> dict[str, Path]:
    """A private copy of the small drive, to damage."""
    root = small["frames"].parent
    shutil.copytree(root, tmp_path / "d")
    return {k: tmp_path / "d" / v.relative_to(root) for k, v in small.items()}


def run(drive: dict[str, Path], *extra: str, poses: bool = True):
    slug = f"ipm-{uuid.uuid4().hex[:8]}"
    args = ["ingest", "ipm", str(drive["frames"]), "--calib", str(drive["calib"]),
            "--layer", slug, *GRID]
    if poses:
        args += ["--poses", str(drive["poses"])]
    return slug, CliRunner().invoke(main, [*args, *extra])


def one_line_error(result, *words: str) -> None:
    assert result.exit_code == 1, result.output
    message = result.output.strip()
    assert message.startswith("Error: ") and "\n" not in message, message
    assert "Traceback" not in result.output
    for w in words:
        assert w in message, message


def shift_poses(path: Path, dt: float, keep=lambda t: True) -> None:
    rows = list(csv.reader(path.open()))
    with path.open("w", newline="") as f:
        out = csv.writer(f)
        out.writerow(rows[0])
        for row in rows[1:]:
            if keep(float(row[0])):
                out.writerow([f"{float(row[0]) + dt:.4f}", *row[1:]])


def test_no_pose_in_range_is_one_line_and_writes_nothing(client, drive) -> None:
    shift_poses(drive["poses"], 100.0)
    slug, result = run(drive)
    one_line_error(result, f"no frame could be used: {N} outside the pose stream",
                   "same clock?")
    assert client.get(f"/layers/{slug}").status_code == 404
    job = next(j for j in client.get("/jobs").json()["jobs"] if j["target"] == slug)
    assert job["status"] == "failed" and "outside the pose stream" in job["error"]


def test_bad_frames_mid_drive_are_skipped_and_the_rest_kept(client, drive) -> None:
    frames = sorted(drive["frames"].glob("frame_*.jpg"))
    frames[4].write_bytes(b"this is not a JPEG")
    data = frames[6].read_bytes()
    frames[6].write_bytes(data[: len(data) // 2])  # truncated mid-scan
    frames[8].unlink()
    small = cv2.resize(cv2.imread(str(frames[10])), (512, 256))
    cv2.imwrite(str(frames[10]), small)
    # Poses (every 0.05 s) stop after the 12th frame and have a 0.2 s hole at the 2nd.
    times = frame_times(N)
    shift_poses(drive["poses"], 0.0, keep=lambda t: t < times[11] + 0.06
                and not times[1] - 0.08 < t < times[1] + 0.08)
    slug, result = run(drive, "--max-pose-gap", "0.15")
    assert result.exit_code == 0, result.output
    first = result.output.splitlines()[0]
    assert first.startswith("frames: 7 used, 7 skipped (") and first.endswith(f"of {N}")
    for part in ("3 unreadable", "2 outside the pose stream", "1 wrong image size",
                 "1 in a pose gap"):
        assert part in first, first
    # One example per reason.
    assert "frame_00004.jpg: not a readable image" in result.output
    assert "is 512x256 px but the calibration" in result.output
    info = client.get(f"/layers/{slug}").json()
    assert info["kind"] == "ipm-mosaic" and info["sources"]


def test_truncated_images_are_refused(small) -> None:
    image = cv2.imread(str(small["frames"] / "frame_00000.jpg"))
    for ext in (".jpg", ".png"):
        data = cv2.imencode(ext, image)[1].tobytes()
        assert decode_image(data, "f").shape == image.shape
        for cut in (len(data) - 2, len(data) // 2, 100):
            with pytest.raises(FrameError, match=r"truncated|not a readable"):
                decode_image(data[:cut], "f")


def test_calibration_mistakes(client, drive) -> None:
    calib = drive["calib"].read_text()
    drive["calib"].write_text(calib.replace('"camera_position_m": [\n  0.1,\n  0.2,\n  2.4',
                                            '"camera_position_m": [\n  0.1,\n  0.2,\n  -2.4'))
    slug, result = run(drive)
    one_line_error(result, "below the ground")
    drive["calib"].write_text(calib.replace("1024,\n  512", "2048,\n  1024")
                              .replace('"vehicle_mask": "mask.png"', '"vehicle_mask": ""'))
    slug, result = run(drive)
    one_line_error(result, "is 1024x512 px but the calibration's image_size is 2048x1024")
    assert client.get(f"/layers/{slug}").status_code == 404


def test_pose_and_option_mistakes(client, drive, tmp_path: Path) -> None:
    lines = drive["poses"].read_text().splitlines()
    lines[5], lines[6] = lines[6], lines[5]
    drive["poses"].write_text("\n".join(lines) + "\n")
    _, result = run(drive)
    one_line_error(result, "line 7", "not after the previous", "strictly increase")
    _, result = run(drive, poses=False)
    one_line_error(result, "--poses", "--qr-pose")
    _, result = run(drive, "--frames", "x")
    assert result.exit_code == 2 and "not a:b" in result.output
    _, result = run(drive, "--zone-size", "12")
    assert result.exit_code == 2 and "two numbers" in result.output
    result = CliRunner().invoke(main, ["ingest", "ipm", str(drive["frames"]), "--calib",
                                       str(drive["calib"]), "--poses", str(tmp_path / "x"),
                                       "--layer", "x"])
    assert result.exit_code == 2
    (drive["frames"] / "frames.csv").unlink()
    _, result = run(drive)
    one_line_error(result, "no frames.csv")


def test_a_killed_registration_keeps_the_finished_zones(client, drive, tmp_path,
                                                        monkeypatch) -> None:
    """Zones are written while driving; if the run dies before registering (here: killed
    during the COG step), nothing is registered, and the kept zones ingest as they are."""
    import ingest.ipm.job as job

    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(job, "ingest_raster", killed)
    zones = tmp_path / "zones"
    slug, result = run(drive, "--zones-dir", str(zones))
    assert result.exit_code != 0
    assert client.get(f"/layers/{slug}").status_code == 404
    kept = sorted(zones.glob("zone_*.tif"))
    assert kept
    monkeypatch.undo()
    result = CliRunner().invoke(main, ["ingest", "raster", *map(str, kept), "--layer", slug,
                                       "--kind", "ipm-mosaic"])
    assert result.exit_code == 0, result.output
    assert len(client.get(f"/layers/{slug}").json()["sources"]) == len(kept)


def write_video(drive: dict[str, Path], path: Path) -> Path:
    frames = sorted(drive["frames"].glob("frame_*.jpg"))
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 7.0,
                             CAMERA.image_size)
    for f in frames:
        writer.write(cv2.imread(str(f)))
    writer.release()
    times = path.with_suffix(".csv")
    times.write_text("t\n" + "".join(f"{t:.6f}\n" for t in frame_times(N)))
    return times


def zone_pixels(folder: Path) -> dict[str, np.ndarray]:
    out = {}
    for path in folder.glob("zone_*.tif"):
        with rasterio.open(path) as ds:
            out[path.name] = ds.read()
    return out


def test_video_input_and_a_truncated_video(client, drive, tmp_path: Path) -> None:
    video = tmp_path / "drive.avi"
    times = write_video(drive, video)
    ref, res = tmp_path / "ref", tmp_path / "vid"
    _, result = run(drive, "--zones-dir", str(ref), "--blend", "later")
    assert result.exit_code == 0, result.output
    video_drive = {**drive, "frames": video}
    _, result = run(video_drive, "--frame-times", str(times), "--zones-dir", str(res),
                    "--blend", "later", "--frames", "2:")
    assert result.exit_code == 0, result.output
    assert f"frames: {N - 2} used, 0 skipped" in result.output
    a, b = zone_pixels(ref), zone_pixels(res)
    assert a.keys() == b.keys()
    for name in a:  # the same frames (MJPEG-recompressed), minus the first two
        both = (a[name][3] == 255) & (b[name][3] == 255)
        assert both.sum() > 0.5 * (b[name][3] == 255).sum()
        assert np.abs(a[name][:3].astype(int) - b[name][:3])[:, both].mean() < 6
    _, result = run(video_drive, "--zones-dir", str(tmp_path / "x"))
    one_line_error(result, "--frame-times")
    # A video cut short: the missing frames are counted, the rest is kept.
    data = video.read_bytes()
    video.write_bytes(data[: int(len(data) * 0.6)])
    slug, result = run(video_drive, "--frame-times", str(times))
    assert result.exit_code == 0, result.output
    first = result.output.splitlines()[0]
    assert "unreadable" in first and not first.startswith(f"frames: {N} used")
    assert client.get(f"/layers/{slug}").status_code == 200


def test_poses_from_qr_codes_match_the_pose_stream(client, drive, tmp_path: Path) -> None:
    frames = sorted(drive["frames"].glob("frame_*.jpg"))
    lon, lat, heading = DRIVE.pose(frame_times(N))
    for i, path in enumerate(frames):
        if i == 3:
            continue  # one frame without a code
        pose = Pose(float(frame_times(N)[i]), float(lon[i]), float(lat[i]), float(heading[i]))
        cv2.imwrite(str(path), stamp_pose(cv2.imread(str(path)), pose, "top-right"),
                    [cv2.IMWRITE_JPEG_QUALITY, 95])
    origin = "--origin", f"{DRIVE.pose(0.0)[0]},{DRIVE.pose(0.0)[1]}"
    _, result = run(drive, "--qr-pose", "top-right", poses=False)
    assert result.exit_code == 0, result.output
    assert f"frames: {N - 1} used, 1 skipped (1 no readable QR pose)" in result.output
    # On the same grid, frames 4.. must give the same pixels from QR codes and pose stream.
    ref = tmp_path / "ref"
    _, result = run(drive, "--zones-dir", str(ref), "--frames", "4:", *origin)
    assert result.exit_code == 0, result.output
    _, result = run(drive, "--qr-pose", "top-right", "--zones-dir", str(tmp_path / "qr4"),
                    "--frames", "4:", *origin, poses=False)
    assert result.exit_code == 0, result.output
    a, b = zone_pixels(ref), zone_pixels(tmp_path / "qr4")
    assert a.keys() == b.keys()
    for name in a:
        both = (a[name][3] == 255) & (b[name][3] == 255)
        assert np.abs(a[name][:3].astype(int) - b[name][:3])[:, both].mean() < 2
