"""Google's encoded polyline (OSRM's ``polyline`` and ``polyline6`` geometries), compiled.

The ``polyline`` package encodes one character at a time in Python: about 5 us per
coordinate, a millisecond for a city route's overview and more than the route search itself.
This encodes in a loop compiled by numba (:mod:`app.routing.native`; vectorised with numpy it
still took ~50 us a city route in per-call costs) and gives the same string (same rounding:
half away from zero, as the package and OSRM do). Decoding stays with the package: only
request coordinates are decoded, and they are few.
"""

from __future__ import annotations

import numpy as np

from app.routing.native import kernel

MOST_CHARS = 7  # per number: 5-bit chunks of a zig-zagged delta (360° at precision 6: 31 bits)


def encode(lonlat: np.ndarray, precision: int) -> str:
    """The encoded polyline of ``lonlat`` rows (lon, lat), at ``precision`` decimals."""
    points = np.asarray(lonlat, np.float64).reshape(-1, 2)
    return _encoded(points, 10.0**precision).tobytes().decode("ascii")


@kernel("u1[:](f8[:, :], f8)")
def _encoded(lonlat: np.ndarray, scale: float) -> np.ndarray:
    """The polyline's characters: per point, latitude then longitude, each the difference from
    the previous point's value rounded at ``scale``, zig-zagged and written 5 bits a character,
    low bits first, 0x20 on every character but a number's last, plus 63."""
    out = np.empty(len(lonlat) * 2 * MOST_CHARS, np.uint8)
    n = 0
    last = np.zeros(2, np.int64)
    for i in range(len(lonlat)):
        for axis in (1, 0):
            scaled = lonlat[i, axis] * scale
            value = np.int64(np.floor(abs(scaled) + 0.5) * np.sign(scaled))
            delta = value - last[axis]
            last[axis] = value
            chunks = ~(delta << 1) if delta < 0 else delta << 1
            while chunks >= 0x20:
                out[n] = ((chunks & 0x1F) | 0x20) + 63
                chunks >>= 5
                n += 1
            out[n] = chunks + 63
            n += 1
    return out[:n]
