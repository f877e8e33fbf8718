"""Georeferencing from ground control points: fit, accuracy report, warp.

CSV, one GCP per line, header optional: ``pixel_x, pixel_y, X, Y[, id]``. X/Y are
longitude/latitude (EPSG:4326) unless ``--crs`` names the CRS they are in (e.g. easting /
northing in EPSG:32633). Pixel coordinates are image columns/rows (0, 0 = top-left corner).

Geographic GCPs are converted to the UTM zone of their centroid first, so the fit, the
residuals (in metres) and GDAL's warp all happen in the same metric frame. Methods:

* ``poly1`` (affine, >= 3 GCPs) and ``poly2`` (>= 6): least squares; the report gives the
  in-sample residual of each GCP *and* its leave-one-out residual.
* ``tps`` (thin-plate spline, >= 4): passes exactly through every GCP, so in-sample residuals
  are zero by construction; the honest accuracy figure is the leave-one-out residual (the
  error at a GCP when the surface is fitted without it), which is what the report gives.

The warp itself is GDAL's (``SRC_METHOD=GCP_POLYNOMIAL``/``GCP_TPS`` in a warped VRT whose
grid is already the web-mercator grid of the output zoom, so the COG driver does not resample
a second time).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rasterio
from pyproj import Transformer
from rasterio.control import GroundControlPoint
from rasterio.crs import CRS
from rasterio.enums import Resampling
from rasterio.errors import CRSError
from rasterio.io import DatasetWriter
from rasterio.vrt import WarpedVRT
from rasterio.warp import reproject
from scipy.interpolate import RBFInterpolator

from app.grid import covering_block, utm_epsg, zoom_for_pixel_size
from ingest.raster.cog import write_staged_cog
from ingest.raster.job import IngestReport, ingest_raster
from ingest.raster.sources import Source, SourceError, inspect

METHODS: dict[str, dict[str, Any]] = {"poly1": {"SRC_METHOD": "GCP_POLYNOMIAL", "MAX_GCP_ORDER": 1},
           "poly2": {"SRC_METHOD": "GCP_POLYNOMIAL", "MAX_GCP_ORDER": 2},
           "tps": {"SRC_METHOD": "GCP_TPS"}}
MIN_GCPS = {"poly1": 3, "poly2": 6, "tps": 4}


@dataclass(frozen=True)
class GcpSet:
    """GCPs in a metric CRS: pixel (col, row) -> (easting, northing) metres."""

    ids: list[str]
    pixels: np.ndarray  # (n, 2) col, row
    coords: np.ndarray  # (n, 2) x, y in ``crs``
    crs: CRS

    def control_points(self) -> list[GroundControlPoint]:
        """The GCPs as rasterio/GDAL control points for the warp."""
        return [GroundControlPoint(row=float(r), col=float(c), x=float(x), y=float(y), id=i)
                for i, (c, r), (x, y) in zip(self.ids, self.pixels, self.coords, strict=True)]


@dataclass(frozen=True)
class ResidualRow:
    """One GCP's residuals: in-sample (None for TPS, zero by construction) and leave-one-out, in
    metres."""
    id: str
    pixel_x: float
    pixel_y: float
    fit_m: float | None
    loo_m: float


@dataclass(frozen=True)
class GcpReport:
    """The fit's accuracy report printed by ``ugvmap ingest raster --gcps``."""
    method: str
    rows: list[ResidualRow]
    rmse_fit_m: float | None
    rmse_loo_m: float

    def table(self) -> str:
        """The accuracy table of a survey report (metres)."""
        lines = [f"GCP residuals ({self.method}, metres)",
                 f"{'id':>8} {'pixel_x':>10} {'pixel_y':>10} {'fit':>9} {'leave-1-out':>12}"]
        for r in self.rows:
            fit = "-" if r.fit_m is None else f"{r.fit_m:.3f}"
            lines.append(f"{r.id:>8} {r.pixel_x:10.1f} {r.pixel_y:10.1f} {fit:>9} "
                         f"{r.loo_m:12.3f}")
        fit = "-" if self.rmse_fit_m is None else f"{self.rmse_fit_m:.3f}"
        lines.append(f"{'RMSE':>8} {'':>10} {'':>10} {fit:>9} {self.rmse_loo_m:12.3f}")
        return "\n".join(lines)


def read_gcps(path: Path, crs: str | None) -> GcpSet:
    """Parse the GCP CSV and express the points in a metric CRS."""
    try:
        source_crs = CRS.from_user_input(crs) if crs else CRS.from_epsg(4326)
    except CRSError as exc:
        raise SourceError(f"--crs {crs!r} is not a CRS ({exc})") from exc
    ids: list[str] = []
    pixels: list[tuple[float, float]] = []
    coords: list[tuple[float, float]] = []
    try:
        with path.open(newline="") as fh:
            for n, row in enumerate(csv.reader(fh), start=1):
                cells = [c.strip() for c in row if c.strip()]
                if not cells or cells[0].startswith("#"):
                    continue
                try:
                    px, py, x, y = (float(v) for v in cells[:4])
                except ValueError:
                    if n == 1:
                        continue  # header
                    raise SourceError(f"{path.name}:{n}: expected pixel_x,pixel_y,X,Y[,id]")\
                        from None
                if not all(map(math.isfinite, (px, py, x, y))):
                    raise SourceError(f"{path.name}:{n}: non-finite number")
                ids.append(cells[4] if len(cells) > 4 else str(len(ids) + 1))
                pixels.append((px, py))
                coords.append((x, y))
    except (OSError, UnicodeDecodeError) as exc:
        raise SourceError(f"{path}: cannot read GCP file ({exc})") from exc
    if not pixels:
        raise SourceError(f"{path.name}: no ground control points")
    xy = np.array(coords, float)
    metric = source_crs
    if source_crs.is_geographic:
        lon, lat = xy.mean(axis=0)
        metric = CRS.from_epsg(utm_epsg(lon, lat))
        east, north = Transformer.from_crs(source_crs.to_wkt(), metric.to_wkt(),
                                           always_xy=True).transform(xy[:, 0], xy[:, 1])
        xy = np.column_stack([east, north])
    return GcpSet(ids=ids, pixels=np.array(pixels, float), coords=xy, crs=metric)


def _design(pixels: np.ndarray, order: int, scale: float) -> np.ndarray:
    u, v = (pixels / scale).T
    cols = [np.ones_like(u), u, v] + ([u * u, u * v, v * v] if order == 2 else [])
    return np.column_stack(cols)


def _fit_predict(method: str, pixels: np.ndarray, coords: np.ndarray, at: np.ndarray,
                 scale: float) -> np.ndarray:
    if method == "tps":
        return RBFInterpolator(pixels / scale, coords, kernel="thin_plate_spline")(at / scale)
    order = METHODS[method]["MAX_GCP_ORDER"]
    coef, *_ = np.linalg.lstsq(_design(pixels, order, scale), coords, rcond=None)
    return _design(at, order, scale) @ coef


def residual_report(gcps: GcpSet, method: str, width: int, height: int) -> GcpReport:
    """Per-GCP residuals (in-sample for polynomials, leave-one-out for all) and RMSEs."""
    n = len(gcps.ids)
    if method not in METHODS:
        raise SourceError(f"--gcp-method must be one of {', '.join(METHODS)}")
    if n < MIN_GCPS[method] + 1:
        raise SourceError(f"{method} needs at least {MIN_GCPS[method] + 1} GCPs (the fit "
                          f"and a leave-one-out check), got {n}")
    px = gcps.pixels
    if (px[:, 0] < 0).any() or (px[:, 0] > width).any() or (px[:, 1] < 0).any() \
            or (px[:, 1] > height).any():
        raise SourceError(f"GCP pixel coordinates must lie inside the {width}x{height} image")
    order = 2 if method == "poly2" else 1
    scale = float(max(width, height))
    if np.linalg.matrix_rank(_design(px, order, scale)) < (6 if order == 2 else 3):
        raise SourceError("GCPs are degenerate (collinear or too few distinct points)")
    fit = None
    if method != "tps":
        fit = np.linalg.norm(_fit_predict(method, px, gcps.coords, px, scale) - gcps.coords,
                             axis=1)
    loo = np.empty(n)
    for i in range(n):
        keep = np.arange(n) != i
        pred = _fit_predict(method, px[keep], gcps.coords[keep], px[i:i + 1], scale)
        loo[i] = np.linalg.norm(pred[0] - gcps.coords[i])
    rows = [ResidualRow(gcps.ids[i], float(px[i, 0]), float(px[i, 1]),
                        None if fit is None else float(fit[i]), float(loo[i]))
            for i in range(n)]
    return GcpReport(method=method, rows=rows,
                     rmse_fit_m=None if fit is None else float(np.sqrt((fit**2).mean())),
                     rmse_loo_m=float(np.sqrt((loo**2).mean())))


def gcp_writer(method: str):
    """A ``to_cog`` hook for :func:`ingest.raster.job.ingest_raster`: GDAL's GCP warp.

    GDAL warps (chunk by chunk, bounded memory) into a temporary tiled GeoTIFF that is
    already on the XYZ grid of the output zoom, which the COG driver then copies without
    resampling again. (rasterio's WarpedVRT ignores GCPs once an output grid is imposed.)
    """

    def write(source: Source, dst: Path) -> None:
        options = METHODS[method]
        gcps = source.gcps
        count = len(source.bands)
        with rasterio.open(source.vrt_xml()) as src:
            with WarpedVRT(src, crs="EPSG:3857", **options) as probe:
                # The warped extent, snapped outwards to the XYZ grid of the closest zoom.
                block = covering_block(probe.bounds, zoom_for_pixel_size(probe.res[0]))

            def warp(out: DatasetWriter) -> None:
                reproject(rasterio.band(src, list(range(1, count + 1))),
                          rasterio.band(out, list(range(1, count + 1))),
                          gcps=gcps, src_crs=source.crs, dst_transform=block.transform,
                          dst_crs="EPSG:3857", dst_alpha=count + 1,
                          resampling=Resampling.bilinear, **options)

            write_staged_cog(dst, block, count, source.dtype, warp)

    return write


def inspect_with_gcps(path: Path, gcps: GcpSet) -> Source:
    """Validate ``path`` as an image georeferenced by ``gcps`` (warped by :func:`gcp_writer`)."""
    return inspect(path, gcps=gcps.control_points(), gcp_crs=gcps.crs)


def ingest_with_gcps(path: Path, layer: str, gcps_file: Path, method: str, crs: str | None,
                     **options) -> tuple[GcpReport, IngestReport]:
    """Validate, report the fit accuracy, then ingest ``path`` warped through its GCPs."""
    gcps = read_gcps(gcps_file, crs)
    source = inspect_with_gcps(path, gcps)
    report = residual_report(gcps, method, source.width, source.height)
    ingested = ingest_raster([path], layer, inspect_source=lambda _: source,
                             to_cog=gcp_writer(method), **options)
    return report, ingested
