"""Georeferencing that does not come from the image file itself.

Three survey conventions are supported, each reduced to a CRS plus either an affine
transform or a list of ground control points:

* **World file** (``.pgw/.jgw/.tfw/.wld``, or ``<image>.<ext>w``): six numbers A, D, B, E, C, F
  where C, F locate the *centre* of the top-left pixel (ESRI convention), so the affine origin
  is shifted by half a pixel. The CRS is not in the file, hence ``--crs``.
* **Zone sidecar** (``<image>.zone.json``): the survey's IPM zone scheme. See
  :class:`ZoneSidecar`.
* **GCPs**: see :mod:`ingest.raster.gcps`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from pyproj import Transformer
from rasterio.crs import CRS
from rasterio.transform import Affine

from app.grid import utm_epsg

WORLD_FILE_SUFFIXES = {
    ".png": (".pgw", ".pngw"),
    ".jpg": (".jgw", ".jpgw"),
    ".jpeg": (".jgw", ".jpegw"),
    ".tif": (".tfw", ".tifw"),
    ".tiff": (".tfw", ".tiffw"),
}


class GeorefError(ValueError):
    """The georeferencing of an input is missing, unreadable or implausible."""


def find_world_file(image: Path) -> Path | None:
    """The world file that belongs to ``image``, if there is one next to it."""
    candidates = [*WORLD_FILE_SUFFIXES.get(image.suffix.lower(), ()), ".wld"]
    for suffix in candidates:
        for variant in (suffix, suffix.upper()):
            path = image.with_suffix(variant)
            if path.is_file():
                return path
    return None


def read_world_file(path: Path) -> Affine:
    """Affine transform (pixel corner -> map) from an ESRI world file."""
    try:
        values = [float(v) for v in path.read_text().split()]
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise GeorefError(f"{path}: not a world file ({exc})") from exc
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise GeorefError(f"{path}: a world file has exactly six finite numbers")
    a, d, b, e, c, f = values
    if a * e - b * d == 0:
        raise GeorefError(f"{path}: degenerate world file (zero pixel size)")
    # C, F are the centre of the top-left pixel; GDAL's origin is its outer corner.
    return Affine(a, b, c - a / 2 - b / 2, d, e, f - d / 2 - e / 2)


@dataclass(frozen=True)
class ZoneSidecar:
    """One stitched IPM zone image in the survey's zone scheme.

    JSON (``<image>.zone.json``)::

        {"zone": {"row": 3, "col": 7},
         "origin": {"lat": 48.1371, "lon": 11.5754},
         "resolution_m": 0.06,
         "zone_size_px": [28000, 7000],
         "overlap_px": [5600, 1400],
         "frame": "utm"}

    The map origin is the north-west (top-left) corner of zone (0, 0). Columns grow east,
    rows grow south, and each zone starts ``zone_size - overlap`` pixels after its
    neighbour, so neighbours share ``overlap`` pixels (the survey keeps at least 5/6 of an
    IPM frame). Images are north-up at ``resolution_m`` metres per pixel
    (default 0.06).

    ``frame`` is the local metric frame the images are north-up in:

    * ``"utm"`` (default): the UTM zone that contains the origin. It is what the survey's
      GNSS/INS poses are logged in, every GIS knows it, and its scale error stays below
      0.04 % across a zone, i.e. well under a pixel over a 1.7 km zone image. Zone images
      therefore line up with each other and with orthophotos exactly, with no per-zone
      distortion to model.
    * ``"enu"``: a local east-north tangent plane at the origin (PROJ's ellipsoidal
      orthographic projection). Exact at the origin, but its distortion grows with the square
      of the distance, so it only suits small survey areas; offered for teams whose
      stitching pipeline works in ENU.
    """

    row: int
    col: int
    origin_lat: float
    origin_lon: float
    resolution_m: float = 0.06
    zone_width_px: int = 28000
    zone_height_px: int = 7000
    overlap_x_px: int = 0
    overlap_y_px: int = 0
    frame: str = "utm"

    @classmethod
    def load(cls, path: Path) -> ZoneSidecar:
        """Read and check a zone sidecar; any problem is one GeorefError line naming the file."""
        try:
            doc = json.loads(path.read_text())
            zone, origin = doc["zone"], doc["origin"]
            width, height = doc.get("zone_size_px", [cls.zone_width_px, cls.zone_height_px])
            overlap_x, overlap_y = doc.get("overlap_px", [0, 0])
            sidecar = cls(
                row=int(zone["row"]), col=int(zone["col"]),
                origin_lat=float(origin["lat"]), origin_lon=float(origin["lon"]),
                resolution_m=float(doc.get("resolution_m", cls.resolution_m)),
                zone_width_px=int(width), zone_height_px=int(height),
                overlap_x_px=int(overlap_x), overlap_y_px=int(overlap_y),
                frame=str(doc.get("frame", "utm")).lower(),
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise GeorefError(f"{path}: not a zone sidecar ({exc!r})") from exc
        sidecar.check(path)
        return sidecar

    def check(self, where: Path | str) -> None:
        """Refuse implausible values (origin, resolution, sizes, frame) before anything is written;
        ``where`` (the sidecar file, or what the values came from) starts the message."""
        problems = []
        if not (-84 <= self.origin_lat <= 84 and -180 <= self.origin_lon <= 180):
            problems.append("origin outside the UTM latitude band / longitude range")
        if not 0.001 <= self.resolution_m <= 100:
            problems.append(f"resolution_m {self.resolution_m} is not plausible")
        if self.zone_width_px <= 0 or self.zone_height_px <= 0:
            problems.append("zone_size_px must be positive")
        if not (0 <= self.overlap_x_px < self.zone_width_px
                and 0 <= self.overlap_y_px < self.zone_height_px):
            problems.append("overlap_px must be >= 0 and smaller than the zone size")
        if self.frame not in ("utm", "enu"):
            problems.append(f"frame must be 'utm' or 'enu', not {self.frame!r}")
        if problems:
            raise GeorefError(f"{where}: " + "; ".join(problems))

    def crs(self) -> CRS:
        """The metric frame the zone image is north-up in: the origin's UTM zone, or a local tangent
        plane."""
        if self.frame == "enu":
            return CRS.from_string(f"+proj=ortho +lat_0={self.origin_lat} "
                                   f"+lon_0={self.origin_lon} +ellps=WGS84 +units=m +no_defs")
        return CRS.from_epsg(utm_epsg(self.origin_lon, self.origin_lat))

    def transform(self) -> Affine:
        """Affine transform of this zone's image in :meth:`crs`."""
        to_frame = Transformer.from_crs("EPSG:4326", self.crs().to_wkt(), always_xy=True)
        east0, north0 = to_frame.transform(self.origin_lon, self.origin_lat)
        step_x = (self.zone_width_px - self.overlap_x_px) * self.resolution_m
        step_y = (self.zone_height_px - self.overlap_y_px) * self.resolution_m
        west = east0 + self.col * step_x
        north = north0 - self.row * step_y
        return Affine(self.resolution_m, 0.0, west, 0.0, -self.resolution_m, north)


def find_zone_sidecar(image: Path) -> Path | None:
    """The zone sidecar of an image (``img.tif.zone.json`` or ``img.zone.json``), if any."""
    for candidate in (image.with_name(image.name + ".zone.json"),
                      image.with_suffix(".zone.json")):
        if candidate.is_file():
            return candidate
    return None
