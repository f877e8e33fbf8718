"""The QR pose codec: encode -> stamp -> (JPEG) -> decode."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ingest.ipm.poses import Pose
from ingest.ipm.qrpose import CORNERS, decode_pose, encode_pose, read_pose, stamp_pose

POSES = [Pose(12.345, 17.6012345, 48.1509876, 359.99),
         Pose(86399.999, -122.4194155, -37.8136276, 0.0),
         Pose(0.0, 179.9999999, 84.9, 123.45)]


@pytest.mark.parametrize("corner", CORNERS)
def test_stamped_pose_reads_back(corner: str) -> None:
    rng = np.random.default_rng(3)
    for pose in POSES:
        frame = rng.integers(0, 256, (512, 1024, 3), dtype=np.uint8)
        stamped = stamp_pose(frame, pose, corner)
        _, jpeg = cv2.imencode(".jpg", stamped, [cv2.IMWRITE_JPEG_QUALITY, 85])
        got = read_pose(cv2.imdecode(jpeg, cv2.IMREAD_COLOR), corner)
        assert got is not None
        assert got.t == pytest.approx(pose.t, abs=5e-4)
        assert (got.lon, got.lat) == pytest.approx((pose.lon, pose.lat), abs=5e-8)
        assert (got.heading_deg - pose.heading_deg + 180) % 360 - 180 == pytest.approx(0,
                                                                                 abs=5e-3)
        # Only the corner changed.
        changed = np.nonzero((stamped != frame).any(axis=2))
        assert changed[0].size and np.ptp(changed[0]) < 128 and np.ptp(changed[1]) < 128


def test_codec_refuses_what_is_not_a_pose() -> None:
    assert decode_pose(encode_pose(POSES[0])) is not None
    for text in ("", "hello", "UGVPOSE1,1,2,3", "UGVPOSE1,a,b,c,d", "OTHER,1,2,3,4",
                 "UGVPOSE1,1,2000000000,0,0"):
        assert decode_pose(text) is None
    noise = np.random.default_rng(0).integers(0, 256, (512, 1024, 3), dtype=np.uint8)
    assert read_pose(noise, "top-left") is None
    with pytest.raises(ValueError, match="does not fit"):
        stamp_pose(np.zeros((64, 128, 3), np.uint8), POSES[0], "top-left", module_px=4)
