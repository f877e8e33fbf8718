"""The survey's zone grid, and poses expressed in it.

The grid is exactly the zone scheme of the zone sidecar (:class:`ingest.raster.georef.
ZoneSidecar`): a fixed origin (north-west corner of zone (0, 0)), north-up pixels of
``resolution_m`` in the UTM zone of the origin, fixed-size zones that start
``zone_size - overlap`` pixels after their neighbour. "Global pixels" below are continuous
pixel coordinates of that grid measured from the origin (columns east, rows south), so zone
(r, c) covers columns [c · step_x, c · step_x + width) and the rows likewise.

Headings are clockwise from *true* north, but the grid is north-up in *grid* north, which
differs by the meridian convergence (about 2° at 48° N, 2.5° from the central meridian: half
a metre at 15 m). Distances on the grid are the ground's times the projection's scale
factor. Both are applied per pose, from PROJ's own factors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt
from pyproj import Proj, Transformer

from ingest.ipm import IpmInputError
from ingest.raster.georef import GeorefError, ZoneSidecar


@dataclass(frozen=True)
class GridPose:
    """A vehicle pose on the grid: its pose point in global pixels, the grid bearing of its
    forward axis (radians, clockwise from grid north) and the grid scale factor."""

    col: float
    row: float
    bearing: float
    scale: float


@dataclass(frozen=True)
class ZoneGrid:
    """The zone scheme a drive is stitched into; the same fields as a zone sidecar, so every
    zone mosaic it writes lines up with the survey's other zones."""

    origin_lon: float
    origin_lat: float
    resolution_m: float = 0.06
    zone_size_px: tuple[int, int] = (2048, 2048)
    overlap_px: tuple[int, int] = (128, 128)

    @classmethod
    def centred_on(cls, lon: float, lat: float, resolution_m: float,
                   zone_size_px: tuple[int, int], overlap_px: tuple[int, int]) -> ZoneGrid:
        """The grid whose zone (0, 0) has the point lon/lat at the centre of its own part (the
        default for a drive: its first pose), so a short drive needs one zone, not the four
        that meet at an origin placed on it."""
        at_point = cls(lon, lat, resolution_m, zone_size_px, overlap_px)
        crs = at_point.sidecar(0, 0).crs()
        to_crs = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
        east, north = to_crs.transform(lon, lat)
        sx, sy = at_point.step_px
        west, top = to_crs.transform(east - sx * resolution_m / 2, north + sy * resolution_m / 2,
                                     direction="INVERSE")
        return cls(west, top, resolution_m, zone_size_px, overlap_px)

    def sidecar(self, row: int, col: int) -> ZoneSidecar:
        """Zone (row, col) as the raster ingest will read it back: the stitcher takes its CRS
        and transform from here, so the zone mosaics and the ingest cannot disagree on
        georeference."""
        return ZoneSidecar(row=row, col=col, origin_lat=self.origin_lat,
                           origin_lon=self.origin_lon, resolution_m=self.resolution_m,
                           zone_width_px=self.zone_size_px[0],
                           zone_height_px=self.zone_size_px[1],
                           overlap_x_px=self.overlap_px[0], overlap_y_px=self.overlap_px[1])

    def check(self) -> None:
        """Refuse an implausible grid (origin, resolution, sizes) as :class:`IpmInputError`
        before any frame is read, by the raster ingest's own sidecar rules."""
        try:
            # The sidecar names its file in the message; the grid has none yet, only a label.
            self.sidecar(0, 0).check("the zone grid")
        except GeorefError as exc:
            raise IpmInputError(str(exc)) from exc

    @property
    def step_px(self) -> tuple[int, int]:
        """(x, y) pixels from one zone's origin to the next: the zone size less the overlap."""
        return (self.zone_size_px[0] - self.overlap_px[0],
                self.zone_size_px[1] - self.overlap_px[1])

    @cached_property
    def _frame(self) -> tuple[Transformer, Proj, float, float]:
        zone = self.sidecar(0, 0)
        crs = zone.crs()
        transform = zone.transform()
        return (Transformer.from_crs("EPSG:4326", crs, always_xy=True), Proj(crs),
                transform.c, transform.f)

    def to_grid(self, lon: npt.ArrayLike, lat: npt.ArrayLike,
                heading_deg: npt.ArrayLike) -> list[GridPose]:
        """Grid poses of lon/lat/heading (degrees, heading clockwise from true north)."""
        to_crs, proj, west, north = self._frame
        east, northing = to_crs.transform(np.asarray(lon, float), np.asarray(lat, float))
        factors = proj.get_factors(np.asarray(lon, float), np.asarray(lat, float))
        # PROJ's convergence is the angle from grid north to true north, counter-clockwise:
        # true north has grid bearing -convergence.
        bearing = np.radians(np.asarray(heading_deg, float)
                             - np.asarray(factors.meridian_convergence))
        scale = np.asarray(factors.meridional_scale, float)
        cols = (np.atleast_1d(east) - west) / self.resolution_m
        rows = (north - np.atleast_1d(northing)) / self.resolution_m
        return [GridPose(float(c), float(r), float(b), float(s)) for c, r, b, s in
                zip(cols, rows, np.atleast_1d(bearing), np.atleast_1d(scale), strict=True)]

    def zone_box(self, row: int, col: int) -> tuple[int, int, int, int]:
        """(col0, row0, col1, row1) global pixels of zone (row, col), end exclusive."""
        sx, sy = self.step_px
        return (col * sx, row * sy, col * sx + self.zone_size_px[0],
                row * sy + self.zone_size_px[1])

    def zones_meeting(self, col0: int, row0: int, col1: int,
                      row1: int) -> list[tuple[int, int]]:
        """Zones (row, col) that share a pixel with the box [col0, col1) x [row0, row1)."""
        sx, sy = self.step_px
        width, height = self.zone_size_px
        cols = range(math.floor((col0 - width) / sx) + 1, math.floor((col1 - 1) / sx) + 1)
        rows = range(math.floor((row0 - height) / sy) + 1, math.floor((row1 - 1) / sy) + 1)
        return [(r, c) for r in rows for c in cols]
