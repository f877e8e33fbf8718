"""Synthetic DEMs with known heights, for terrain tests and benchmarks.

Heights are functions of *map* coordinates (metres east/north in the DEM's CRS), so a test
knows the true height and slope anywhere, whatever grid the DEM was written on.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.transform import Affine

Surface = Callable[[np.ndarray, np.ndarray], np.ndarray]


def hills(origin: tuple[float, float]) -> Surface:
    """Rolling hills (slopes up to ~35 degrees) around ``origin`` (east, north), 300 m base."""
    e0, n0 = origin

    def surface(east: np.ndarray, north: np.ndarray) -> np.ndarray:
        x, y = east - e0, north - n0
        return (300 + 40 * np.sin(x / 37.0) * np.cos(y / 23.0) + 0.15 * x
                + 60 * np.exp(-((x - 150) ** 2 + (y + 120) ** 2) / 60.0 ** 2))
    return surface


def plane(origin: tuple[float, float], east_grade: float, north_grade: float,
          base: float) -> Surface:
    """A tilted plane: ``base`` at ``origin``, rising ``east_grade`` m per m east, etc."""
    e0, n0 = origin
    return lambda east, north: base + east_grade * (east - e0) + north_grade * (north - n0)


def write_dem(path: Path, surface: Surface, crs: CRS | None, transform: Affine, width: int,
              height: int, dtype: str = "float32", nodata: float | None = -9999.0,
              hole: tuple[slice, slice] | None = None) -> np.ndarray:
    """Write ``surface`` sampled at the pixel centres of a north-up grid as a GeoTIFF DEM
    (``hole``: rows, cols set to ``nodata``); return the heights written."""
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    east = transform.c + cols * transform.a
    north = transform.f + rows * transform.e
    z = surface(east, north)
    z = (np.round(z) if np.dtype(dtype).kind in "iu" else z).astype(dtype)
    if hole is not None:
        assert nodata is not None
        z[hole] = nodata
    profile = {"driver": "GTiff", "width": width, "height": height, "count": 1,
               "dtype": dtype, "nodata": nodata}
    if crs is not None:
        profile.update(crs=crs, transform=transform)
    else:
        profile.update(transform=transform)
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(z, 1)
    return z


def ridge_with_pass(origin: tuple[float, float], ridge_x: float = 750.0,
                    pass_y: float = -850.0) -> Surface:
    """A plain at 100 m crossed north-south by a ridge 80 m high at ``ridge_x`` m east of
    ``origin`` (its flanks ~50 degrees), lowered to 8 m (~8 degrees) at a pass ``pass_y`` m
    north of it (negative: south)."""
    e0, n0 = origin

    def surface(east: np.ndarray, north: np.ndarray) -> np.ndarray:
        x, y = east - e0, north - n0
        height = 80 * (1 - 0.9 * np.exp(-((y - pass_y) / 90.0) ** 2))
        return 100 + height * np.exp(-((x - ridge_x) / 45.0) ** 2)
    return surface


def disk_mask(path: Path, crs: CRS, transform: Affine, width: int, height: int,
              centre: tuple[float, float], radius_m: float) -> np.ndarray:
    """A uint8 GeoTIFF, 1 inside a disk (map coordinates) and 0 elsewhere: a lake to forbid."""
    cols, rows = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    east = transform.c + cols * transform.a
    north = transform.f + rows * transform.e
    lake = (np.hypot(east - centre[0], north - centre[1]) <= radius_m).astype(np.uint8)
    with rasterio.open(path, "w", driver="GTiff", width=width, height=height, count=1,
                       dtype="uint8", crs=crs, transform=transform) as ds:
        ds.write(lake, 1)
    return lake
