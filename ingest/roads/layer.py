"""``ugvmap ingest roads``: extract the road network of a stored raster layer into PostGIS.

The layer's sources are merged (top source first, masks honoured) into one temporary
GeoTIFF on the finest source grid, so overlapping zones are extracted once rather than per
file (which would store every road twice where zones overlap). Training samples are given in
map coordinates (lon/lat boxes, or road centerlines from a vector file) because a layer has no
pixel grid a user could point at; they are burnt into the label image on the mosaic's grid.
The extracted graph goes through the network importer's ``write_network``, so it obeys the
same topology rules as any imported file.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rasterio
import shapely
from pyproj import Transformer
from rasterio.crs import CRS
from rasterio.features import rasterize
from rasterio.merge import merge
from rasterio.transform import Affine
from shapely.geometry import box, shape
from shapely.geometry.base import BaseGeometry
from sqlalchemy.orm import Session

from app.tiles.catalog import get_layer
from app.tiles.store import open_store
from ingest.network import ImportSummary, RoadAttributes, RoadLine, write_network
from ingest.roads import RoadsInputError
from ingest.roads.classify import NOT_ROAD, ROAD
from ingest.roads.georef import read_image
from ingest.roads.pipeline import Extraction, ExtractParams, extract_roads

LonLatBox = tuple[float, float, float, float]
MAX_LANES = 8
MAX_MOSAIC_PX = 40_000 * 40_000
"""Refuse layers whose mosaic would not fit a 2-core / 24 GiB machine's memory."""


@dataclass(frozen=True)
class GeoSample:
    """Training sample in lon/lat: road boxes, not-road boxes, road centerlines (+ width)."""

    road_boxes: Sequence[LonLatBox] = ()
    not_road_boxes: Sequence[LonLatBox] = ()
    road_lines: Sequence[object] = ()
    """Shapely geometries (lon/lat) of known road centerlines."""
    line_width_m: float = 6.0


def layer_source_paths(session: Session, slug: str) -> list[str]:
    """The layer's COGs, the one drawn on top first (what ``merge`` keeps where they overlap)."""
    layer = get_layer(session.connection(), slug)
    if layer is None:
        raise RoadsInputError(f"no raster layer {slug!r} (see `ugvmap layers list`)")
    store = open_store()
    return [store.resolve(source["uri"]) for source in reversed(layer["sources"])]


def merge_sources(paths: Sequence[str], dst: Path) -> None:
    """Write the mosaic of ``paths`` (all EPSG:3857) at the finest source resolution."""
    datasets = [rasterio.open(p) for p in paths]
    try:
        res = min(min(abs(d.res[0]), abs(d.res[1])) for d in datasets)
        left = min(d.bounds.left for d in datasets)
        right = max(d.bounds.right for d in datasets)
        bottom = min(d.bounds.bottom for d in datasets)
        top = max(d.bounds.top for d in datasets)
        if (right - left) / res * (top - bottom) / res > MAX_MOSAIC_PX:
            raise RoadsInputError("the layer is too large to extract in one go; extract its "
                                  "source images one by one with `ugvmap extract-roads`")
        colour = [i for i, c in enumerate(datasets[0].colorinterp, 1)
                  if c.name != "alpha"] or [1]
        # The COGs are JPEG/YCbCr; the scratch mosaic is plain lossless RGB (or grey).
        photometric = "RGB" if len(colour) == 3 else "MINISBLACK"
        merge(datasets, res=res, indexes=colour, nodata=0, dst_path=dst,
              dst_kwds={"driver": "GTiff", "tiled": True, "compress": "deflate",
                        "photometric": photometric})
    finally:
        for d in datasets:
            d.close()


def sample_labels(shape: tuple[int, int], to_map: Affine, crs: CRS,
                  sample: GeoSample) -> np.ndarray:
    """Burn a lon/lat training sample into a 255 road / 128 not road / 0 label image."""
    transformer = Transformer.from_crs("EPSG:4326", crs, always_xy=True)

    def reproject_geometry(geom: BaseGeometry) -> BaseGeometry:
        return shapely.transform(geom, lambda xy: np.column_stack(
            transformer.transform(xy[:, 0], xy[:, 1])))

    def burn(geoms: list, value: int, labels: np.ndarray) -> None:
        if geoms:
            rasterize([(g, value) for g in geoms], out=labels, transform=to_map)

    labels = np.zeros(shape, np.uint8)
    burn([reproject_geometry(box(*b)) for b in sample.not_road_boxes], NOT_ROAD, labels)
    lines = [reproject_geometry(g) for g in sample.road_lines]
    if lines:
        # Far from every known road is "not road"; near the centerline is road.
        near = np.zeros(shape, np.uint8)
        burn([g.buffer(sample.line_width_m * 3) for g in lines], 1, near)
        labels[(near == 0) & (labels == 0)] = NOT_ROAD
    burn([reproject_geometry(box(*b)) for b in sample.road_boxes], ROAD, labels)
    burn([g.buffer(sample.line_width_m / 2) for g in lines], ROAD, labels)
    if not (labels == ROAD).any():
        raise RoadsInputError("the training sample does not cover any road pixel of the layer: "
                              "check that the boxes / lines lie on the layer (lon/lat)")
    return labels


def road_lines(extraction: Extraction, attrs: dict) -> list[RoadLine]:
    """Extracted edges as lon/lat RoadLines; total lanes (capped at the store's 8, since a
    blob wider than any road says nothing about lanes) split over both directions."""
    to_lonlat = Transformer.from_crs(extraction.frame.crs, "EPSG:4326", always_xy=True)
    lines = []
    for edge in extraction.graph.edges:
        xs, ys = extraction.frame.to_output @ (edge.coords[:, 0], edge.coords[:, 1])
        lon, lat = to_lonlat.transform(np.asarray(xs), np.asarray(ys))
        lanes = min(max(edge.lanes, 1), MAX_LANES)
        attributes = RoadAttributes(
            lanes_forward=(lanes + 1) // 2, lanes_backward=max(1, lanes // 2),
            width_m=round(edge.width_m, 2) if edge.width_m > 0 else None, attrs=dict(attrs))
        lines.append(RoadLine(list(zip(lon.tolist(), lat.tolist(), strict=True)), attributes))
    return lines


def ingest_layer_roads(session: Session, slug: str, network: str, sample: GeoSample | None,
                       params: ExtractParams, *, replace: bool = False,
                       progress: bool = False) -> tuple[Extraction, ImportSummary]:
    """Extract layer ``slug``'s roads into network ``network`` in the caller's transaction
    (``sample`` None: the road model zero-shot)."""
    paths = layer_source_paths(session, slug)
    if not paths:
        raise RoadsInputError(f"layer {slug!r} has no sources")
    with tempfile.TemporaryDirectory(prefix="ugvmap-roads-") as tmp:
        mosaic = Path(tmp) / "mosaic.tif"
        merge_sources(paths, mosaic)
        image = read_image(mosaic)
    labels = (None if sample is None
              else sample_labels(image.pixels.shape[:2], image.transform, image.crs, sample))
    extraction = extract_roads(image, labels, params, progress=progress)
    if not extraction.graph.edges:
        raise RoadsInputError(f"no road found in layer {slug!r} with the "
                              f"{extraction.classifier} classifier; check the training sample")
    lines = road_lines(extraction, {"extracted_from": slug, "classifier": extraction.classifier})
    summary = write_network(session, network, lines, replace=replace, node_crossings=False)
    return extraction, summary


def read_sample_lines(path: Path) -> list[object]:
    """Road centerlines (lon/lat) from a GeoJSON file, as shapely geometries."""
    try:
        features = json.loads(path.read_text())["features"]
        return [shape(f["geometry"]) for f in features if f.get("geometry")]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise RoadsInputError(f"{path}: not a GeoJSON FeatureCollection of lines ({exc})") from exc
