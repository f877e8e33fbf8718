"""Synthetic georeferenced imagery with known content, and tile stitching, for raster tests.

The pattern is a smooth function of *map* coordinates, so any image of it (any zone, any
CRS placement) shows the same thing at the same place: a seam or a misplacement shows up as
a difference from the function itself.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import morecantile
import numpy as np
import rasterio
from pyproj import Transformer
from rasterio.crs import CRS
from rasterio.transform import Affine, from_origin
from rasterio.warp import Resampling, reproject

TMS = morecantile.tms.get("WebMercatorQuad")
UTM33 = CRS.from_epsg(32633)


def pattern(east: np.ndarray, north: np.ndarray) -> np.ndarray:
    """RGB (3, H, W) uint8 in 30..200, smooth at the sub-metre scale."""
    r = 115 + 85 * np.sin(east / 9.0)
    g = 115 + 85 * np.cos(north / 11.0)
    b = 115 + 60 * np.sin((east + north) / 13.0)
    return np.stack([r, g, b]).round().astype(np.uint8)


def pattern_image(transform: Affine, width: int, height: int) -> np.ndarray:
    """The pattern sampled at the pixel centres of a north-up grid."""
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    east = transform.c + cols * transform.a
    north = transform.f + rows * transform.e
    return pattern(east, north)


def write_tif(path: Path, data: np.ndarray, crs: CRS | None, transform: Affine | None,
              alpha: np.ndarray | None = None, **extra) -> Path:
    """A GeoTIFF of ``data`` (bands first), with an alpha band when given."""
    bands = data if alpha is None else np.concatenate([data, alpha[None]])
    profile = {"driver": "GTiff", "width": data.shape[2], "height": data.shape[1],
               "count": bands.shape[0], "dtype": str(bands.dtype), **extra}
    if crs is not None:
        profile.update(crs=crs, transform=transform)
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(bands)
        if alpha is not None:
            ds.colorinterp = [*ds.colorinterp[:-1], rasterio.enums.ColorInterp.alpha]
    return path


def utm_origin(lon: float = 15.2, lat: float = 48.3) -> tuple[float, float]:
    """UTM 33N easting/northing of a lon/lat (default: a point in Austria)."""
    return Transformer.from_crs("EPSG:4326", UTM33, always_xy=True).transform(lon, lat)


def synthetic_utm(path: Path, width: int = 900, height: int = 700, res: float = 0.3,
                  origin: tuple[float, float] | None = None) -> tuple[Path, Affine]:
    """A UTM 33N GeoTIFF of the pattern at ``res`` m per pixel, and its transform."""
    east, north = origin or utm_origin()
    transform = from_origin(round(east), round(north), res, res)
    return write_tif(path, pattern_image(transform, width, height), UTM33, transform), transform


def tiles_around(lon: float, lat: float, zoom: int, n: int = 3) -> tuple[int, int, int, int]:
    """(x0, y0, nx, ny): an n x n block of tiles centred on lon/lat."""
    t = TMS.tile(lon, lat, zoom)
    return t.x - n // 2, t.y - n // 2, n, n


def grid_transform(zoom: int, x0: int, y0: int, size: int = 256) -> Affine:
    """The transform of a stitched tile block whose top-left tile is x0, y0 (EPSG:3857)."""
    b = TMS.xy_bounds(morecantile.Tile(x0, y0, zoom))
    res = (b.right - b.left) / size
    return from_origin(b.left, b.top, res, res)


def decode_rgba(body: bytes) -> np.ndarray:
    """An encoded tile (PNG, JPEG, WebP, grey or colour) as an RGBA array."""
    img = cv2.imdecode(np.frombuffer(body, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img is not None, "not an image"
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGRA)
    elif img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2BGRA)
    return cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)


def stitch(get, slug: str, zoom: int, block: tuple[int, int, int, int],
           fmt: str = "png") -> np.ndarray:
    """Fetch a block of tiles over HTTP (``get(url) -> response``) as one RGBA array."""
    x0, y0, nx, ny = block
    rows = []
    for y in range(y0, y0 + ny):
        row = []
        for x in range(x0, x0 + nx):
            resp = get(f"/tiles/{slug}/{zoom}/{x}/{y}.{fmt}")
            assert resp.status_code == 200, resp.text
            row.append(decode_rgba(resp.content))
        rows.append(np.concatenate(row, axis=1))
    return np.concatenate(rows, axis=0)


def reference(path: Path, zoom: int, block: tuple[int, int, int, int]) -> np.ndarray:
    """The source resampled (bilinear) to the same tile grid, as RGBA (alpha from its mask)."""
    x0, y0, nx, ny = block
    transform = grid_transform(zoom, x0, y0)
    out = np.zeros((4, ny * 256, nx * 256), np.uint8)
    with rasterio.open(path) as src:
        for i in range(3):
            reproject(rasterio.band(src, i + 1), out[i], dst_transform=transform,
                      dst_crs="EPSG:3857", resampling=Resampling.bilinear)
        reproject(src.dataset_mask(), out[3], src_transform=src.transform, src_crs=src.crs,
                  dst_transform=transform, dst_crs="EPSG:3857", resampling=Resampling.nearest)
    return np.moveaxis(out, 0, -1)


def lonlat_to_pixel(lon: float, lat: float, zoom: int, x0: int, y0: int) -> tuple[float, float]:
    """Pixel (col, row) of lon/lat in a stitched block whose top-left tile is x0, y0."""
    x, y = TMS.xy(lon, lat)
    inv = ~grid_transform(zoom, x0, y0)
    return inv @ (x, y)


def centroid(mask: np.ndarray) -> tuple[float, float]:
    """Pixel (col, row) centre of the true pixels of ``mask``."""
    rows, cols = np.nonzero(mask)
    assert rows.size, "marker not found"
    return float(cols.mean()) + 0.5, float(rows.mean()) + 0.5


def mae(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference of two uint8 images."""
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())


def haversine_m(lon1: float, lat1: float, lon2: float, lat2: float) -> float:
    """Great-circle distance in metres (mean Earth radius)."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp, dl = p2 - p1, math.radians(lon2 - lon1)
    h = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * 6371008.8 * math.asin(math.sqrt(h))
