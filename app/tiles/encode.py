"""Tile encoding with OpenCV: several times faster than GDAL's or Pillow's PNG path.

PNG uses zlib level 1 with Huffman-only coding: aerial imagery barely compresses with LZ77
anyway, so this is ~2x faster than zlib's default strategy for ~4 % more bytes (measured on
the benchmark texture: 3.5 ms and 160 kB vs 7 ms and 155 kB per 256 px tile). Fully opaque
tiles are written without the alpha channel.
JPEG has no alpha: uncovered pixels become white, the background of the web map.

A tile with no valid pixel (outside coverage) is a constant per format and size, encoded once
at maximum compression: ~330 bytes of PNG instead of the 33 kB a Huffman-only all-transparent
tile costs. It is a normal 200 image rather than a 204: every XYZ client draws an image without
an error path (Leaflet reports a 204 as a ``tileerror``), and HTTP caches keep it under the
same versioned-URL rules as any other tile.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

MEDIA_TYPES = {"png": "image/png", "jpg": "image/jpeg", "webp": "image/webp"}
PNG_LEVEL = 1
JPEG_QUALITY = 85
WEBP_QUALITY = 85
BACKGROUND = 255


def encode(bgra: np.ndarray, fmt: str) -> bytes:
    """Encode a BGRA tile as ``png``, ``jpg`` or ``webp``."""
    alpha = bgra[..., 3]
    if not alpha.any():
        return empty_tile(fmt, bgra.shape[0])
    opaque = bool(alpha.min() == 255)
    if fmt == "jpg":
        image = bgra[..., :3] if opaque else _flatten(bgra)
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    elif fmt == "webp":
        ok, buf = cv2.imencode(".webp", bgra[..., :3] if opaque else bgra,
                               [cv2.IMWRITE_WEBP_QUALITY, WEBP_QUALITY])
    else:
        ok, buf = cv2.imencode(".png", bgra[..., :3] if opaque else bgra,
                               [cv2.IMWRITE_PNG_COMPRESSION, PNG_LEVEL,
                                cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY])
    if not ok:
        raise RuntimeError(f"OpenCV could not encode a {fmt} tile")
    return buf.tobytes()


@lru_cache(maxsize=8)
def empty_tile(fmt: str, size: int) -> bytes:
    """The smallest encoding of a tile with nothing in it (transparent; white for JPEG)."""
    if fmt == "jpg":
        params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]
        image = np.full((size, size, 3), BACKGROUND, np.uint8)
    else:
        params = ([cv2.IMWRITE_WEBP_QUALITY, 101] if fmt == "webp"  # > 100: lossless
                  else [cv2.IMWRITE_PNG_COMPRESSION, 9])
        image = np.zeros((size, size, 4), np.uint8)
    ok, buf = cv2.imencode(f".{fmt}", image, params)
    if not ok:
        raise RuntimeError(f"OpenCV could not encode an empty {fmt} tile")
    return buf.tobytes()


def _flatten(bgra: np.ndarray) -> np.ndarray:
    image = bgra[..., :3].copy()
    image[bgra[..., 3] == 0] = BACKGROUND
    return image
