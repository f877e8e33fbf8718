"""Write one source as a Cloud-Optimized GeoTIFF on the web-mercator (XYZ) tile grid.

GDAL's COG driver does the work (reprojection, tiling, overviews, mask); this module only
chooses its options and makes the write atomic. ``TILING_SCHEME=GoogleMapsCompatible`` with
256 px blocks puts the full-resolution raster on the XYZ grid of the closest zoom, so an XYZ
tile at native zoom is exactly one internal block, and each overview is the next zoom out,
down to the zoom where the source fits one tile.

Peak memory is bounded by GDAL's block cache and the warp memory, not by the image size
(GDAL warps and compresses block by block), which is what keeps a 28000 x 7000 zone mosaic
well under 2 GiB: :func:`bound_block_cache`.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
import rasterio.shutil
from rasterio.env import get_gdal_config, set_gdal_config
from rasterio.io import DatasetReader, DatasetWriter
from shapely.geometry import MultiPolygon

from app.grid import TILE_SIZE, TileBlock
from ingest.raster.footprint import footprint_3857

INGEST_BLOCK_CACHE_MB = 256
"""The most GDAL's block cache holds in a process that writes COGs. Measured on a 28000 x 7000
RGB mosaic (``bench/tiles.py --skip-tiles --skip-cache --skip-s3``, 2 cores): 61.8 s and a
peak RSS of 857 MiB with it; 58.8 s and 2612 MiB with GDAL's default (5 % of 24 GiB)."""
#: Longest side of the overview level display ranges are estimated on.
STATS_PX = 1024


def cog_options(dtype: str, band_count: int) -> dict[str, Any]:
    """Creation options: JPEG + mask for 8-bit RGB, lossless ZSTD (+alpha) for the rest."""
    options: dict[str, Any] = {
        "TILING_SCHEME": "GoogleMapsCompatible",
        "BLOCKSIZE": TILE_SIZE,
        "RESAMPLING": "BILINEAR",
        "OVERVIEW_RESAMPLING": "AVERAGE",
        "SPARSE_OK": "TRUE",
        "BIGTIFF": "IF_SAFER",
        "NUM_THREADS": "ALL_CPUS",
    }
    if dtype == "uint8" and band_count == 3:
        options.update(COMPRESS="JPEG", QUALITY=90)
    else:
        options.update(COMPRESS="ZSTD", LEVEL=9,
                       PREDICTOR=3 if dtype.startswith("float") else 2)
    return options


def bound_block_cache() -> None:
    """Lower the process's GDAL block cache to :data:`INGEST_BLOCK_CACHE_MB` where it is larger
    (a smaller ``GDAL_CACHEMAX`` in the environment is kept).

    For the process, on purpose, and never put back: GDAL has one block cache per process,
    which a scoped ``rasterio.Env`` cannot scope. The ``rasterio.Env(GDAL_CACHEMAX=256)`` used
    before set it in bytes, not megabytes (every COG was written with a 256-byte cache), and
    where it was entered with a dataset already open (the GCP warp) it left the process's
    cache at 256 bytes when it ended, so every later read in that process decoded each JPEG
    tile again per row it served (a road extraction's 768 px mosaic: 20 ms -> 5 s). The
    processes that write COGs are ingests (the CLI, the job worker), never the tile server."""
    cap = INGEST_BLOCK_CACHE_MB << 20
    if get_gdal_config("GDAL_CACHEMAX") > cap:
        set_gdal_config("GDAL_CACHEMAX", cap)


def write_cog(src: str | Path | rasterio.io.DatasetReaderBase, dst: Path,
              dtype: str, band_count: int) -> None:
    """Write ``src`` (path, VRT XML or open dataset) to ``dst`` atomically.

    The pyramid is written to a hidden temporary name in the same directory and renamed
    only when complete, so a killed job never leaves a file under a name that looks final.
    """
    bound_block_cache()
    dst.parent.mkdir(parents=True, exist_ok=True)
    stem = f".{dst.name}.{os.getpid()}"
    tmp = dst.with_name(f"{stem}.tmp")
    try:
        with rasterio.Env(GDAL_ERROR_ON_LIBJPEG_WARNING=True, GDAL_TIFF_INTERNAL_MASK=True,
                          CPL_TMPDIR=str(dst.parent)):
            rasterio.shutil.copy(src, tmp, driver="COG", **cog_options(dtype, band_count))
        os.replace(tmp, dst)
    finally:
        # GDAL's own temporaries (CPL_TMPDIR) are named from ours minus its extension:
        # ``<stem>_<pid>_<n>.warped.tif.tmp``.
        for leftover in dst.parent.glob(f"{stem}[._]*"):
            with contextlib.suppress(FileNotFoundError):
                leftover.unlink()


def write_staged_cog(dst: Path, block: TileBlock, bands: int, dtype: str,
                     fill: Callable[[DatasetWriter], None], nodata: float | None = None) -> None:
    """Write a COG whose pixels we compute ourselves (a GCP warp, a layer overview).

    ``fill`` writes ``bands`` data bands plus an alpha band (or, with ``nodata``, the data
    bands alone, ``nodata`` where there is none: heights) into a temporary tiled GeoTIFF
    laid out on ``block`` (so it is already on the XYZ grid and the COG driver copies it
    without resampling again); the COG is then written from it atomically (:func:`write_cog`)
    and the staging file removed, whatever happens.
    """
    profile = {"driver": "GTiff", "width": block.width, "height": block.height,
               "count": bands + 1, "dtype": dtype, "crs": "EPSG:3857",
               "transform": block.transform, "photometric": "RGB" if bands == 3 else "MINISBLACK",
               "alpha": "YES", "tiled": True, "blockxsize": TILE_SIZE, "blockysize": TILE_SIZE,
               "compress": "zstd", "sparse_ok": True}
    if nodata is not None:
        profile.update(count=bands, nodata=nodata)
        del profile["alpha"]
    bound_block_cache()  # the staging file's dirty blocks wait in the cache too
    staged = dst.with_name(f".{dst.name}.staged.tmp")
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        with rasterio.open(staged, "w", **profile) as out:
            fill(out)
        write_cog(staged, dst, dtype, bands)
    finally:
        staged.unlink(missing_ok=True)


@dataclass(frozen=True)
class CogMeasure:
    """What the catalogue records about a written COG, read from one open of the file."""

    zoom: int  # the XYZ zoom of its full resolution
    minzoom: int  # the zoom of its smallest overview
    width: int
    height: int
    band_count: int
    dtype: str
    footprint: MultiPolygon | None  # valid-data outline (EPSG:3857); None: no valid pixel
    display_range: list[list[float]] | None  # per band 2nd-98th percentile; None for 8-bit


def _display_range(ds: DatasetReader) -> list[list[float]] | None:
    """Per-band display range (2nd-98th percentile) for non-8-bit data, from an overview:
    tiles are 8-bit, and a 16-bit or float image needs a stretch chosen once per source."""
    if ds.dtypes[0] == "uint8":
        return None
    scale = max(1, math.ceil(max(ds.width, ds.height) / STATS_PX))
    shape = (ds.count, math.ceil(ds.height / scale), math.ceil(ds.width / scale))
    data = ds.read(out_shape=shape, masked=True)
    ranges = []
    for band in data[: 3 if data.shape[0] >= 3 else 1]:
        valid = band.compressed()
        lo, hi = (float(v) for v in np.percentile(valid, [2, 98])) if valid.size else (0, 1)
        ranges.append([lo, hi if hi > lo else lo + 1])
    return ranges


def measure_cog(path: Path) -> CogMeasure:
    """Zoom range, size, footprint and display range of a COG written by :func:`write_cog`."""
    with rasterio.open(path) as ds:
        zoom = int(ds.tags(ns="TILING_SCHEME").get("ZOOM_LEVEL", 0))
        return CogMeasure(zoom=zoom, minzoom=max(0, zoom - len(ds.overviews(1))),
                          width=ds.width, height=ds.height, band_count=ds.count,
                          dtype=ds.dtypes[0], footprint=footprint_3857(ds),
                          display_range=_display_range(ds))
