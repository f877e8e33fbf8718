"""Top-down view of one panorama, to check a calibration before a whole drive.

    python -m ingest.ipm.preview PANO.jpg --calib calib.json --out top.png [--window 40]

Writes the ground window the drive would sample from this frame (vehicle forward up, camera
at the centre, transparent where nothing is written), i.e. exactly what ``ugvmap ingest ipm``
places on the map for it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from ingest.ipm.calibration import Calibration, load_calibration
from ingest.ipm.frames import decode_image
from ingest.ipm.lookup import build_lookup, sample_patch


def topdown(pano: np.ndarray, calib: Calibration, window_m: float, resolution_m: float,
            range_m: float) -> np.ndarray:
    """(n, n, 4) BGRA: the panorama's ground window, alpha 0 where nothing is written."""
    patch = sample_patch(pano, build_lookup(calib, window_m, resolution_m, range_m))
    patch[..., :3][patch[..., 3] == 0] = 0
    return patch


def main() -> None:
    """Command line entry point (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("pano", type=Path)
    parser.add_argument("--calib", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--window", type=float, default=40.0, help="metres")
    parser.add_argument("--resolution", type=float, default=0.05, help="metres per pixel")
    parser.add_argument("--range", type=float, help="metres [default: half the window]")
    args = parser.parse_args()
    calib = load_calibration(args.calib)
    pano = decode_image(args.pano.read_bytes(), args.pano.name)
    view = topdown(pano, calib, args.window, args.resolution, args.range or args.window / 2)
    cv2.imwrite(str(args.out), view)
    print(f"{args.out}: {view.shape[1]}x{view.shape[0]} px at {args.resolution} m/px, "
          f"{(view[..., 3] > 0).mean():.0%} ground")


if __name__ == "__main__":
    main()
