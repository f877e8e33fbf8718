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
