"""Reading imagery of any band count/dtype, its size in metres, and pixel -> output coordinates.

Every threshold of the pipeline is in metres, so the first thing we need from an image is how
many metres one pixel covers: from its georeference when it has one (geodesic for a geographic
CRS), else from the user (``--resolution``). Extraction runs on a *working grid* that may be
coarser than the source (roads are metres wide; 0.16 m pixels only cost time), and
:class:`Frame` maps working-grid pixels back to source pixels or map coordinates.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import rasterio
from pyproj import CRS, Geod, Transformer
from rasterio.enums import ColorInterp
from rasterio.errors import NotGeoreferencedWarning, RasterioIOError
from rasterio.transform import Affine

from ingest.roads import RoadsInputError

MIN_SIDE_PX = 16
"""Smallest working image side that can hold a road plus its surroundings."""


@dataclass(frozen=True)
class Image:
    """Pixels as float32 (rows, cols, bands), with where they are and how big they are."""

    pixels: np.ndarray
    valid: np.ndarray | None
    """False where the source says "no data" (alpha 0 / nodata); None when all is valid."""
    transform: Affine | None
    """Source pixel (col, row) corner -> map coordinates; None for a plain picture."""
    crs: CRS | None
    resolution_m: float


@dataclass(frozen=True)
class Frame:
    """Where working-grid pixel centres land in the output coordinates."""

    to_output: Affine
    """Working pixel (col, row) corner coordinates -> output (x, y)."""
    crs: CRS | None
    resolution_m: float
    """Metres per working pixel."""
    to_source: Affine
    """Working pixel corner coordinates -> source pixel corner coordinates."""


def _scale_to_unit(data: np.ndarray) -> np.ndarray:
    """(bands, rows, cols) of any dtype -> (rows, cols, bands) float32; integers scaled to
    [0, 1] by their dtype range. Each band is converted straight into its place in the
    interleaved output: a 6000 x 6000 RGB image is 430 MB as float32, so every extra copy
    counts, and an interleaved copy of the input first (then converted) took 1 s of a drive's
    27 MP mosaic, against 0.2 s."""
    out = np.empty((*data.shape[1:], data.shape[0]), np.float32)
    for i, band in enumerate(data):
        out[..., i] = band
    if np.issubdtype(data.dtype, np.integer):
        info = np.iinfo(data.dtype)
        if info.min:
            out -= info.min
        out *= 1.0 / float(info.max - info.min)
    else:
        np.nan_to_num(out, copy=False)
    return out


def pixel_size_m(transform: Affine, crs: CRS, shape: tuple[int, int]) -> float:
    """Geometric mean of the pixel's east-west and north-south ground size, in metres.

    Measured on the ellipsoid at the image centre, because a projected CRS's grid unit is not a
    ground metre everywhere: a web-mercator pixel (every stored layer) covers cos(latitude)
    of its nominal size, 0.8x at Las Vegas and 0.5x at Helsinki.
    """
    cx, cy = transform @ (shape[1] / 2, shape[0] / 2)
    ex, ey = transform @ (shape[1] / 2 + 1, shape[0] / 2)
    sx, sy = transform @ (shape[1] / 2, shape[0] / 2 + 1)
    if not crs.is_geographic:
        to_lonlat = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
        (cx, ex, sx), (cy, ey, sy) = to_lonlat.transform([cx, ex, sx], [cy, ey, sy])
    geod = Geod(ellps="WGS84")
    dx = geod.inv(cx, cy, ex, ey)[2]
    dy = geod.inv(cx, cy, sx, sy)[2]
    return math.sqrt(dx * dy)


@contextmanager
def open_raster(path: str | Path) -> Iterator[rasterio.DatasetReader]:
    """``rasterio.open`` that accepts plain pictures quietly and fails as a user error."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as src:
                yield src
    except RasterioIOError as exc:
        raise RoadsInputError(f"{path}: not a readable image ({exc})") from exc


def georeference(src: rasterio.DatasetReader) -> tuple[Affine | None, CRS | None]:
    """(transform, CRS) of a dataset, or (None, None) for a picture without georeference."""
    if src.crs is None:
        return None, None
    return src.transform, CRS.from_user_input(src.crs)


def read_band(path: str | Path) -> tuple[np.ndarray, Affine | None, CRS | None]:
    """Band 1 as stored (label and mask images), with its georeference if any."""
    with open_raster(path) as src:
        return (src.read(1), *georeference(src))


def read_image(path: str | Path, resolution_m: float | None = None) -> Image:
    """Read any raster GDAL understands; alpha bands become the validity mask.

    ``resolution_m`` is required when the file has no georeference and overrides it otherwise.
    """
    with open_raster(path) as src:
        alpha = [i for i, c in enumerate(src.colorinterp, 1) if c == ColorInterp.alpha]
        bands = [i for i in range(1, src.count + 1) if i not in alpha] or [1]
        data = src.read(bands)
        valid = src.read(alpha[0]) > 0 if alpha else None
        if valid is None and src.nodata is not None:
            valid = src.read_masks(1) > 0
        transform, crs = georeference(src)
    if resolution_m is None:
        if transform is None or crs is None:
            raise RoadsInputError(
                f"{path} has no georeference: give its resolution with --resolution M "
                "(metres per pixel)")
        resolution_m = pixel_size_m(transform, crs, data.shape[1:])
    if not resolution_m > 0:
        raise RoadsInputError(f"resolution must be a positive number of metres, not {resolution_m}")
    return as_image(data, valid, transform, crs, resolution_m)


def as_image(data: np.ndarray, valid: np.ndarray | None, transform: Affine | None,
             crs: CRS | None, resolution_m: float) -> Image:
    """An :class:`Image` of bands read elsewhere ((bands, rows, cols), any dtype; e.g. a
    mosaic merged in memory), consuming ``data``."""
    pixels = _scale_to_unit(data)
    del data
    if valid is not None and valid.all():
        valid = None
    return Image(pixels=pixels, valid=valid, transform=transform, crs=crs,
                 resolution_m=float(resolution_m))


def working_shape(shape: tuple[int, int], resolution_m: float,
                  work_resolution_m: float | None, upsample: bool = False) -> tuple[int, int]:
    """Grid size at ``work_resolution_m`` (never finer than the source unless ``upsample``)."""
    if work_resolution_m is None or (
            abs(work_resolution_m / resolution_m - 1) <= 0.05 if upsample
            else work_resolution_m <= resolution_m * 1.05):
        return shape
    factor = work_resolution_m / resolution_m
    return max(1, round(shape[0] / factor)), max(1, round(shape[1] / factor))


def to_working_grid(image: Image, work_resolution_m: float | None, upsample: bool = False
                    ) -> tuple[np.ndarray, np.ndarray | None, Frame]:
    """Resample pixels (area average; bilinear when ``upsample`` makes the grid finer) and
    validity to the working grid, with its frame.

    Colour classifiers never need a grid finer than the source; a road model does: it learned
    road widths in pixels of its own size, so coarser imagery is enlarged to it."""
    rows, cols = image.pixels.shape[:2]
    wrows, wcols = working_shape((rows, cols), image.resolution_m, work_resolution_m, upsample)
    if min(wrows, wcols) < MIN_SIDE_PX:
        raise RoadsInputError(
            f"image is {cols}x{rows} px ({wcols}x{wrows} on the working grid): too small to "
            f"hold a road, need at least {MIN_SIDE_PX} px a side")
    to_source = Affine.scale(cols / wcols, rows / wrows)
    if (wrows, wcols) == (rows, cols):
        pixels, valid = image.pixels, image.valid
    else:
        finer = wrows > rows
        pixels = resize(image.pixels, (wrows, wcols),
                        cv2.INTER_LINEAR if finer else cv2.INTER_AREA)
        valid = None if image.valid is None else resize(
            image.valid.astype(np.uint8), (wrows, wcols), cv2.INTER_NEAREST).astype(bool)
    to_output = (image.transform or Affine.identity()) @ to_source
    res = image.resolution_m * math.sqrt(to_source.a * to_source.e)
    return pixels, valid, Frame(to_output=to_output, crs=image.crs, resolution_m=res,
                                to_source=to_source)


def resize(array: np.ndarray, shape: tuple[int, int], interpolation: int) -> np.ndarray:
    """cv2.resize for any channel count (OpenCV caps channels at 512 and wants (w, h))."""
    if array.ndim == 3 and array.shape[2] > 4:
        return np.stack([resize(array[..., i], shape, interpolation)
                         for i in range(array.shape[2])], axis=-1)
    out = cv2.resize(array, (shape[1], shape[0]), interpolation=interpolation)
    return out[..., None] if array.ndim == 3 and out.ndim == 2 else out


def crs_member(crs: CRS | None, resolution_m: float) -> dict:
    """GeoJSON top-level members naming the coordinate space of the output."""
    if crs is None:
        return {"crs": None, "coordinate_space": "pixel",
                "coordinate_note": "source image pixel coordinates (x = column, y = row, "
                                   "pixel corners at integers); the image has no georeference",
                "resolution_m": resolution_m}
    epsg = crs.to_epsg()
    name = ("urn:ogc:def:crs:OGC:1.3:CRS84" if epsg == 4326
            else f"urn:ogc:def:crs:EPSG::{epsg}" if epsg else crs.to_wkt())
    return {"crs": {"type": "name", "properties": {"name": name}},
            "coordinate_space": "map", "resolution_m": resolution_m}
