"""The real street panorama (``../shared/data/panorama``) seen from above with a guessed
calibration (camera 2.5 m high, level, nadir fill masked): a sensible ground patch."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from ingest.ipm.calibration import load_calibration
from ingest.ipm.frames import decode_image
from ingest.ipm.preview import topdown

RESOLUTION = 0.05


def test_real_panorama_gives_a_road_from_above(shared_data: Path, tmp_path: Path) -> None:
    pano_path = shared_data / "panorama" / "street_intersection_equirect.jpg"
    if not pano_path.is_file():
        pytest.skip(f"{pano_path} is absent")
    pano = decode_image(pano_path.read_bytes(), pano_path.name)
    height, width = pano.shape[:2]
    mask = np.zeros((height, width), np.uint8)
    mask[int(height * 0.88):] = 255  # the filled-in nadir
    cv2.imwrite(str(tmp_path / "mask.png"), mask)

    def view(pitch_deg: float) -> np.ndarray:
        (tmp_path / "calib.json").write_text(json.dumps({
            "image_size": [width, height], "camera_position_m": [0, 0, 2.5],
            "pitch_deg": pitch_deg, "roll_deg": 0, "yaw_deg": 0, "vehicle_mask": "mask.png"}))
        return topdown(pano, load_calibration(tmp_path / "calib.json"), 50.0, RESOLUTION, 25.0)

    level = view(0.0)
    valid = level[..., 3] > 0
    assert valid.mean() > 0.7
    # Mostly grey asphalt...
    hsv = cv2.cvtColor(level[..., :3], cv2.COLOR_BGR2HSV)
    assert np.median(hsv[..., 1][valid]) < 50
    # ...with long, straight road markings, many of them parallel (the zebra crossings).
    count, parallel = straight_markings(level)
    assert count >= 20 and parallel >= 8
    # A camera pitched 8° the wrong way bends and scatters them.
    assert straight_markings(view(8.0))[1] < parallel / 2


def straight_markings(view: np.ndarray) -> tuple[int, int]:
    """(segments of white marking >= 2.5 m, most of them within one 5° direction bin)."""
    bright = (cv2.cvtColor(view[..., :3], cv2.COLOR_BGR2GRAY) > 190) & (view[..., 3] > 0)
    edges = cv2.Canny(bright.astype(np.uint8) * 255, 50, 150)
    found = cv2.HoughLinesP(edges, 1, np.pi / 360, 40, minLineLength=round(2.5 / RESOLUTION),
                            maxLineGap=3)
    segments = np.zeros((0, 4)) if found is None else found.reshape(-1, 4)
    angles = np.degrees(np.arctan2(segments[:, 3] - segments[:, 1],
                                   segments[:, 2] - segments[:, 0])) % 180
    return len(segments), int(np.histogram(angles, bins=36, range=(0, 180))[0].max())
