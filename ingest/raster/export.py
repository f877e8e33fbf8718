"""``ugvmap layers export``: a whole raster layer as one Cloud-Optimized GeoTIFF.

GDAL does the work: the layer's sources become one VRT in paint order (bottom first, each
painted through its own mask, so a newer source covers an older one and nodata never paints),
on the web-mercator grid of the finest source, and the COG driver writes it with the same
options as ingest (:func:`ingest.raster.cog.write_cog`), block by block in bounded memory.
Pixels keep their type (a 16-bit layer exports 16-bit, not the display stretch of tiles).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

import rasterio
from rasterio.crs import CRS

from app.db.session import get_engine
from app.errors import UserError
from app.grid import covering_block, pixel_size_m
from app.tiles.catalog import get_layer
from app.tiles.readers import open_raster
from app.tiles.store import open_store
from ingest.raster.cog import write_cog
from ingest.raster.sources import GDAL_TYPES, colour_bands


class ExportError(UserError):
    """The layer cannot be exported as asked; the message says why."""


@dataclass(frozen=True)
class PlacedSource:
    """One source COG and where it lands on the export grid (pixels)."""

    path: str
    bands: list[int]
    width: int
    height: int
    dst: tuple[float, float, float, float]  # x, y, width, height on the export grid


def _complex(path: str, band: int | str, src: PlacedSource, tail: str) -> str:
    x, y, w, h = src.dst
    return (f'<ComplexSource resampling="bilinear"><SourceFilename relativeToVRT="0">'
            f"{escape(path)}</SourceFilename><SourceBand>{band}</SourceBand>"
            f'<SrcRect xOff="0" yOff="0" xSize="{src.width}" ySize="{src.height}"/>'
            f'<DstRect xOff="{x!r}" yOff="{y!r}" xSize="{w!r}" ySize="{h!r}"/>'
            f"{tail}</ComplexSource>")


def layer_vrt(sources: list[PlacedSource], width: int, height: int,
              transform: rasterio.Affine, dtype: str, band_count: int) -> str:
    """The VRT of ``sources`` (bottom first): each data band painted through its source's mask
    (``UseMaskBand``), and a mask that is valid wherever any source is."""
    names = ("Red", "Green", "Blue") if band_count == 3 else ("Gray",)
    parts = [f'<VRTDataset rasterXSize="{width}" rasterYSize="{height}">',
             f"<SRS>{escape(CRS.from_epsg(3857).to_wkt())}</SRS>",
             "<GeoTransform>" + ",".join(repr(v) for v in transform.to_gdal()) + "</GeoTransform>"]
    for i, name in enumerate(names, start=1):
        parts.append(f'<VRTRasterBand dataType="{GDAL_TYPES[dtype]}" band="{i}">'
                     f"<ColorInterp>{name}</ColorInterp>")
        parts.extend(_complex(s.path, s.bands[min(i, len(s.bands)) - 1], s,
                              "<UseMaskBand>true</UseMaskBand>") for s in sources)
        parts.append("</VRTRasterBand>")
    # Each source's mask is 0/255: paint only its 255s, so later sources never erase coverage.
    parts.append('<MaskBand><VRTRasterBand dataType="Byte">')
    parts.extend(_complex(s.path, "mask,1", s, "<NODATA>0</NODATA>") for s in sources)
    parts.append("</VRTRasterBand></MaskBand></VRTDataset>")
    return "".join(parts)


def export_layer(slug: str, out: Path, database_url: str | None = None) -> int:
    """Write layer ``slug`` as one COG at ``out`` (atomically); return its XYZ zoom."""
    with get_engine(database_url).connect() as conn:
        layer = get_layer(conn, slug)
    if layer is None:
        raise ExportError(f"no raster layer {slug!r}")
    if not layer["sources"]:
        raise ExportError(f"layer {slug!r} has no sources")
    dtypes = sorted({s["dtype"] for s in layer["sources"]})
    if len(dtypes) > 1:
        raise ExportError(f"layer {slug!r} mixes {' and '.join(dtypes)} sources; one COG "
                          "has one pixel type")
    store = open_store()
    zoom = max(s["zoom"] for s in layer["sources"])
    opened = []
    for source in layer["sources"]:  # paint order, bottom first
        path = store.resolve(source["uri"])
        with open_raster(path) as ds:
            opened.append((path, colour_bands(ds), ds.width, ds.height, ds.bounds))
    left = min(b.left for *_, b in opened)
    bottom = min(b.bottom for *_, b in opened)
    right = max(b.right for *_, b in opened)
    top = max(b.top for *_, b in opened)
    block = covering_block((left, bottom, right, top), zoom)
    res = pixel_size_m(zoom)
    origin_x, origin_y = block.transform.c, block.transform.f
    placed = [PlacedSource(path, bands, w, h, ((b.left - origin_x) / res, (origin_y - b.top) / res,
                                                (b.right - b.left) / res, (b.top - b.bottom) / res))
              for path, bands, w, h, b in opened]
    band_count = 3 if any(len(p.bands) >= 3 for p in placed) else 1
    vrt = layer_vrt(placed, block.width, block.height, block.transform, dtypes[0], band_count)
    write_cog(vrt, out.resolve(), dtypes[0], band_count)
    return zoom
