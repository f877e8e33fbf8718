"""Validate one input image and describe it as a GDAL VRT that the COG writer can consume.

Validation happens before anything is written, so a corrupt, truncated, non-image or absurd
input is refused with one clear message and leaves the store and the catalogue untouched.

The VRT normalises every band layout the survey produces (RGB, RGBA, RGB + mask, RGB +
nodata, single band, uint8/uint16) into "up to three colour bands + one per-dataset mask":
GDAL's warper honours such a mask, the COG driver then writes JPEG + internal mask for
8-bit RGB (cheap tiles, no lossy nodata halo = no black borders) and an alpha band for
lossless encodings. Georeferencing that is not in the file (world file, zone sidecar, GCPs)
is written into the same VRT, so the pixels are never copied before the final warp.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

import pyproj
import rasterio
from rasterio.control import GroundControlPoint
from rasterio.crs import CRS
from rasterio.enums import MaskFlags
from rasterio.errors import CRSError, NotGeoreferencedWarning, RasterioError
from rasterio.transform import Affine
from rasterio.warp import transform_bounds
from rasterio.windows import Window
from shapely.geometry import box

from app.errors import UserError
from ingest.raster.georef import (
    GeorefError,
    ZoneSidecar,
    find_world_file,
    find_zone_sidecar,
    read_world_file,
)

#: Largest accepted input, in pixels per side and in total (a 28000 x 7000 zone is 0.2 Gpx).
MAX_SIDE_PX = 200_000
MAX_PIXELS = 8_000_000_000
#: Pixel sizes outside this range (metres) are georeferencing mistakes, not imagery.
MIN_RES_M, MAX_RES_M = 0.001, 50_000.0
#: The nodata value of elevation COGs (no DEM has land 32 km below the sea).
HEIGHT_NODATA = -32768.0
GDAL_TYPES = {"uint8": "Byte", "uint16": "UInt16", "int16": "Int16", "uint32": "UInt32",
              "int32": "Int32", "float32": "Float32", "float64": "Float64"}
#: Reading these makes libjpeg/libtiff/libpng complaints about truncated data hard errors.
STRICT_READ_ENV = {"GDAL_ERROR_ON_LIBJPEG_WARNING": "TRUE", "GDAL_PAM_ENABLED": "NO"}


class SourceError(UserError):
    """An input image that cannot be ingested; the message says why, in one line."""


@dataclass
class Source:
    """A validated input: where its pixels are and how to read them."""

    path: Path
    width: int
    height: int
    dtype: str
    bands: list[int]
    crs: CRS
    transform: Affine | None
    georef_from: str
    gcps: list[GroundControlPoint] = field(default_factory=list)
    bounds_4326: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    #: False when every pixel is valid (no nodata, alpha or mask): no mask to carry over.
    has_mask: bool = True
    band_count: int = 0
    warnings: list[str] = field(default_factory=list)
    """What looks wrong but is not refused (a world file placing it outside its CRS's area)."""
    heights: bool = False
    """An elevation source (:func:`as_elevation`): float32 with :data:`HEIGHT_NODATA` where
    the input has no data, instead of a mask (GDAL takes no float alpha band as a mask)."""

    @property
    def name(self) -> str:
        """The file name, used in messages and as the source's catalogue name."""
        return self.path.name

    def cog_input(self) -> str:
        """What the COG driver reads: the file itself when nothing needs normalising (it is
        measurably faster than a VRT on big mosaics), else :meth:`vrt_xml`."""
        plain = (self.georef_from == "file" and not self.has_mask and not self.heights
                 and self.bands == list(range(1, self.band_count + 1)))
        return str(self.path) if plain else self.vrt_xml()

    def vrt_xml(self) -> str:
        """The input as a VRT: chosen colour bands, explicit georeferencing, one mask band."""
        path = escape(str(self.path.resolve()))

        def simple(band: int | str) -> str:
            return (f'<SimpleSource><SourceFilename relativeToVRT="0">{path}</SourceFilename>'
                    f"<SourceBand>{band}</SourceBand></SimpleSource>")

        parts = [f'<VRTDataset rasterXSize="{self.width}" rasterYSize="{self.height}">']
        if self.gcps:
            parts.append(f"<GCPList Projection={quoteattr(self.crs.to_wkt())}>")
            parts.extend(f'<GCP Id="{i}" Pixel="{g.col!r}" Line="{g.row!r}" X="{g.x!r}" '
                         f'Y="{g.y!r}"/>' for i, g in enumerate(self.gcps))
            parts.append("</GCPList>")
        else:
            assert self.transform is not None
            parts.append(f"<SRS>{escape(self.crs.to_wkt())}</SRS>")
            parts.append("<GeoTransform>" + ",".join(repr(v) for v in self.transform.to_gdal())
                         + "</GeoTransform>")
        names = ("Red", "Green", "Blue") if len(self.bands) == 3 else ("Gray",)
        gdal_type = GDAL_TYPES[self.dtype]
        if self.heights:  # masked pixels (nodata, alpha, mask) become the band's nodata
            parts.append(
                f'<VRTRasterBand dataType="Float32" band="1"><NoDataValue>{HEIGHT_NODATA!r}'
                f'</NoDataValue><ComplexSource><SourceFilename relativeToVRT="0">{path}'
                f"</SourceFilename><SourceBand>{self.bands[0]}</SourceBand>"
                "<UseMaskBand>true</UseMaskBand></ComplexSource></VRTRasterBand></VRTDataset>")
            return "".join(parts)
        for i, (band, interp) in enumerate(zip(self.bands, names, strict=True), start=1):
            parts.append(f'<VRTRasterBand dataType="{gdal_type}" band="{i}">'
                         f"<ColorInterp>{interp}</ColorInterp>{simple(band)}</VRTRasterBand>")
        if self.has_mask:
            # "mask,1" is what GDAL derives for band 1: alpha band, internal mask or nodata.
            parts.append(f'<MaskBand><VRTRasterBand dataType="Byte">{simple("mask,1")}'
                         "</VRTRasterBand></MaskBand>")
        parts.append("</VRTDataset>")
        return "".join(parts)


def colour_bands(ds: rasterio.io.DatasetReader) -> list[int]:
    """Bands to keep: the first three non-alpha bands, or the first one for gray/2-band."""
    bands = [b for b, ci in zip(ds.indexes, ds.colorinterp, strict=True) if ci.name != "alpha"]
    if not bands:
        raise SourceError(f"{ds.name}: only alpha bands, no image data")
    return bands[:3] if len(bands) >= 3 else bands[:1]


def _resolve_georef(path: Path, ds: rasterio.io.DatasetReader, crs: str | None,
                    gcps: Sequence[GroundControlPoint] | None,
                    gcp_crs: CRS | None) -> tuple[CRS, Affine | None, str]:
    if gcps:
        assert gcp_crs is not None
        return gcp_crs, None, "gcps"
    sidecar = find_zone_sidecar(path)
    if sidecar is not None:
        zone = ZoneSidecar.load(sidecar)
        if (ds.width, ds.height) != (zone.zone_width_px, zone.zone_height_px):
            raise SourceError(f"{path.name}: image is {ds.width}x{ds.height} px but its zone "
                              f"sidecar says {zone.zone_width_px}x{zone.zone_height_px}")
        return zone.crs(), zone.transform(), "zone"
    world = find_world_file(path)
    user_crs = None
    if crs:
        try:
            user_crs = CRS.from_user_input(crs)
        except CRSError as exc:
            raise SourceError(f"--crs {crs!r} is not a CRS ({exc})") from exc
    if world is not None:
        if user_crs is None and ds.crs is None:
            raise SourceError(f"{path.name}: has a world file ({world.name}) but no CRS; "
                              "pass --crs (e.g. --crs EPSG:32633)")
        return user_crs or ds.crs, read_world_file(world), "world-file"
    if ds.crs is not None and not ds.transform.is_identity:
        return ds.crs, ds.transform, "file"
    raise SourceError(f"{path.name}: not georeferenced (no CRS/transform in the file, no world "
                      "file, no .zone.json sidecar, no --gcps)")


def _check_plausible(path: Path, src: Source) -> None:
    if src.transform is not None:
        res_x = math.hypot(src.transform.a, src.transform.d)
        res_y = math.hypot(src.transform.b, src.transform.e)
        metres = src.crs.linear_units_factor[1] if src.crs.is_projected else 111_320.0
        res_m = min(res_x, res_y) * metres
        if not MIN_RES_M <= res_m <= MAX_RES_M:
            raise SourceError(f"{path.name}: pixel size {res_m:.4g} m is not plausible"
                              + _units_mismatch(src))
        corners = [src.transform @ (c, r) for c in (0, src.width) for r in (0, src.height)]
        xs, ys = [c[0] for c in corners], [c[1] for c in corners]
        left, bottom, right, top = min(xs), min(ys), max(xs), max(ys)
    else:
        xs = [g.x for g in src.gcps]
        ys = [g.y for g in src.gcps]
        left, bottom, right, top = min(xs), min(ys), max(xs), max(ys)
    try:
        west, south, east, north = transform_bounds(src.crs, "EPSG:4326",
                                                    left, bottom, right, top)
    except (RasterioError, CRSError) as exc:
        raise SourceError(f"{path.name}: bounds cannot be projected ({exc})") from exc
    if not (all(map(math.isfinite, (west, south, east, north)))
            and -180 <= west < east <= 180 and -85.06 <= south < north <= 85.06):
        raise SourceError(f"{path.name}: bounds ({west:.4f}, {south:.4f}, {east:.4f}, "
                          f"{north:.4f}) are outside the web-mercator world; wrong --crs?"
                          + _units_mismatch(src))
    src.bounds_4326 = (west, south, east, north)
    area = pyproj.CRS.from_user_input(src.crs.to_string()).area_of_use
    if src.georef_from == "world-file" and area is not None and not box(
            area.west, area.south, area.east, area.north).buffer(1.0).contains(
            box(west, south, east, north)):
        src.warnings.append(
            f"{path.name}: its world file puts it at {(west + east) / 2:.4f},"
            f"{(south + north) / 2:.4f} (lon,lat), outside where {src.crs.to_string()} is "
            f"used ({area.name}: {area.west:g},{area.south:g},{area.east:g},{area.north:g}); "
            "check --crs")


def _units_mismatch(src: Source) -> str:
    """Why a world file's numbers may not fit the CRS they were given with: degree-sized
    numbers in a metric CRS, or metre-sized ones in a geographic CRS ("" when neither)."""
    if src.georef_from != "world-file" or src.transform is None:
        return ""
    t = src.transform
    looks_like_degrees = abs(t.c) <= 180 and abs(t.f) <= 90 and abs(t.a) < 0.01
    if src.crs.is_projected and looks_like_degrees:
        return (f": the world file's numbers look like degrees (origin {t.c:.6g},{t.f:.6g}, "
                f"pixel {abs(t.a):.3g}) but --crs {src.crs.to_string()} is in metres; "
                "a lon/lat world file wants --crs EPSG:4326")
    if src.crs.is_geographic and not looks_like_degrees:
        return (f": the world file's numbers look like metres (origin {t.c:.6g},{t.f:.6g}, "
                f"pixel {abs(t.a):.3g}) but --crs {src.crs.to_string()} is in degrees; "
                "give the projected CRS they were measured in (e.g. a UTM zone, EPSG:326NN)")
    return ""


def _describe(path: Path, ds: rasterio.io.DatasetReader, crs: str | None,
              gcps: Sequence[GroundControlPoint] | None, gcp_crs: CRS | None) -> Source:
    if not 0 < ds.width <= MAX_SIDE_PX or not 0 < ds.height <= MAX_SIDE_PX \
            or ds.width * ds.height > MAX_PIXELS:
        raise SourceError(f"{path.name}: {ds.width}x{ds.height} px is outside the "
                          f"accepted size (<= {MAX_SIDE_PX} px a side)")
    dtype = ds.dtypes[0]
    if dtype not in GDAL_TYPES or len(set(ds.dtypes)) != 1:
        raise SourceError(f"{path.name}: unsupported pixel type {ds.dtypes}")
    bands = colour_bands(ds)
    try:
        src_crs, transform, how = _resolve_georef(path, ds, crs, gcps, gcp_crs)
    except GeorefError as exc:
        raise SourceError(str(exc)) from exc
    # The last row sits at the end of strip/sequential formats: a truncated file fails
    # here instead of half-way through writing the pyramid.
    for row in sorted({0, ds.height // 2, ds.height - 1}):
        try:
            ds.read(bands, window=Window(0, row, ds.width, 1))
        except RasterioError as exc:
            raise SourceError(f"{path.name}: a damaged image: pixel row {row + 1} of "
                              f"{ds.height} cannot be read ({DAMAGED})") from exc
    has_mask = any(MaskFlags.all_valid not in flags for flags in ds.mask_flag_enums)
    return Source(path=path, width=ds.width, height=ds.height, dtype=dtype, bands=bands,
                  crs=src_crs, transform=transform, georef_from=how, gcps=list(gcps or []),
                  has_mask=has_mask, band_count=ds.count)


def as_elevation(source: Source) -> Source:
    """The source as heights: its first band as float32, nodata carried as the mask.

    Float32 whatever the input type, so the bilinear warp and the averaging overviews keep
    fractions of a metre (an int16 SRTM tile averaged in int16 would round every level);
    a file of several colour bands is a picture, not heights, and is refused.
    """
    if len(source.bands) > 1:
        raise SourceError(f"{source.name}: an elevation layer needs heights in one band; "
                          f"this file has {len(source.bands)} colour bands (a picture?)")
    return replace(source, dtype="float32", heights=True)


DAMAGED = "the file is cut short or corrupt"


def _unopenable(exc: RasterioError) -> str:
    """Why GDAL could not open a file, in our words: GDAL's own text names a C function or
    advises a driver prefix, neither of which tells a user what is wrong with the file."""
    if "Permission denied" in str(exc):
        return "cannot be read (permission denied)"
    if "not recognized as being in a supported file format" in str(exc):
        return ("not an image: its content is in no raster format GDAL reads (GeoTIFF, PNG, "
                "JPEG, ... were expected)")
    return f"a damaged image: its header cannot be read ({DAMAGED})"


def inspect(path: Path, crs: str | None = None,
            gcps: Sequence[GroundControlPoint] | None = None,
            gcp_crs: CRS | None = None) -> Source:
    """Open and check one input without writing anything; raise :class:`SourceError`."""
    if not path.is_file():
        raise SourceError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise SourceError(f"{path}: empty file")
    try:
        with warnings.catch_warnings(), rasterio.Env(**STRICT_READ_ENV):
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            with rasterio.open(path) as ds:
                source = _describe(path, ds, crs, gcps, gcp_crs)
    except RasterioError as exc:
        raise SourceError(f"{path.name}: {_unopenable(exc)}") from exc
    _check_plausible(path, source)
    return source
