"""Poses stamped into the frames as QR codes (how the survey burned poses into its video).

Payload, integers only so it survives any text handling: ``UGVPOSE1,<t_ms>,<lon_e7>,<lat_e7>,
<heading_cdeg>`` (time in milliseconds, lon/lat in 1e-7 degrees (≈ 1 cm), heading in
hundredths of a degree clockwise from true north). The code is stamped black on white
into one corner of the frame and must fit in that corner's H/4 x H/4 square, where it is
looked for. Decoding uses OpenCV's ``QRCodeDetector``, with its ArUco-based detector as a
second opinion (each misses codes the other reads).
"""

from __future__ import annotations

import cv2
import numpy as np

from ingest.ipm.poses import Pose

PREFIX = "UGVPOSE1"
CORNERS = ("top-left", "top-right", "bottom-left", "bottom-right")


def encode_pose(pose: Pose) -> str:
    """The payload :func:`stamp_pose` burns into a frame and :func:`decode_pose` reads."""
    return (f"{PREFIX},{round(pose.t * 1000)},{round(pose.lon * 1e7)},"
            f"{round(pose.lat * 1e7)},{round(pose.heading_deg * 100) % 36000}")


def decode_pose(text: str) -> Pose | None:
    """The pose in a payload, or None if it is not one of ours."""
    parts = text.strip().split(",")
    if len(parts) != 5 or parts[0] != PREFIX:
        return None
    try:
        t_ms, lon, lat, hdg = (int(p) for p in parts[1:])
    except ValueError:
        return None
    if not (-1_800_000_000 <= lon <= 1_800_000_000 and -900_000_000 <= lat <= 900_000_000):
        return None
    return Pose(t_ms / 1000, lon / 1e7, lat / 1e7, hdg / 100)


def corner_box(size: tuple[int, int], corner: str) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of the square a corner's code must fit in."""
    width, height = size
    side = height // 4
    x0 = 0 if corner.endswith("left") else width - side
    y0 = 0 if corner.startswith("top") else height - side
    return x0, y0, x0 + side, y0 + side


def stamp_pose(frame: np.ndarray, pose: Pose, corner: str = "top-left",
               module_px: int = 3) -> np.ndarray:
    """A copy of ``frame`` with ``pose`` as a QR code (with its white quiet zone) in
    ``corner``; raise ValueError if the code does not fit the corner's square."""
    code = cv2.QRCodeEncoder.create().encode(encode_pose(pose))
    code = cv2.resize(code, None, fx=module_px, fy=module_px, interpolation=cv2.INTER_NEAREST)
    x0, y0, x1, y1 = corner_box((frame.shape[1], frame.shape[0]), corner)
    if code.shape[0] > y1 - y0:
        raise ValueError(f"a {code.shape[0]} px code does not fit a {y1 - y0} px corner")
    out = frame.copy()
    x = x0 if corner.endswith("left") else x1 - code.shape[1]
    y = y0 if corner.startswith("top") else y1 - code.shape[0]
    out[y:y + code.shape[0], x:x + code.shape[1]] = code[..., None] if out.ndim == 3 else code
    return out


def read_pose(frame: np.ndarray, corner: str) -> Pose | None:
    """The pose stamped in ``frame``'s ``corner``, or None if no code of ours is there."""
    x0, y0, x1, y1 = corner_box((frame.shape[1], frame.shape[0]), corner)
    roi = frame[y0:y1, x0:x1]
    grey = cv2.cvtColor(roi, cv2.COLOR_BGR2GRAY) if roi.ndim == 3 else roi
    for detector in (cv2.QRCodeDetector(), cv2.QRCodeDetectorAruco()):
        text = detector.detectAndDecode(grey)[0]
        if text:
            return decode_pose(text)
    return None
