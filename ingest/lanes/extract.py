"""The lane-marking chain on one image, and its GeoJSON.

Pixels are read as they are (no resampling: a marking is a few pixels wide and any resampling
blurs it); coordinates go out in the image's CRS when it has one, else in source pixels, the
way ``extract-roads`` writes them.
"""

from __future__ import annotations

import cv2
import numpy as np

from ingest.lanes import check_resolution
from ingest.lanes.across import BOUNDING
from ingest.lanes.classify import ClassifyParams, Marking, classify
from ingest.lanes.crossing import crossings
from ingest.lanes.paint import PaintParams, brightness, near_road, paint_mask, road_surface, top_hat
from ingest.lanes.trace import pieces
from ingest.roads.georef import Image, crs_member


def rgb_of(pixels: np.ndarray) -> np.ndarray:
    """(rows, cols, 3) float32 RGB in [0, 1] from 1, 3 or 4 bands (grey repeated)."""
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.shape[2] < 3:
        pixels = np.repeat(pixels[..., :1], 3, axis=2)
    return np.ascontiguousarray(pixels[..., :3], np.float32)


def extract_markings(image: Image, paint: PaintParams | None = None,
                     params: ClassifyParams | None = None,
                     road: np.ndarray | None = None) -> list[Marking]:
    """Every marking line in ``image`` (pixel coordinates), zebra bars joined into crossings
    (:mod:`ingest.lanes.crossing`); refuses imagery too coarse.
    ``road`` (bool, the image's grid), where given, is where paint may be
    (:func:`ingest.lanes.road.model_road`), beside the colour test."""
    check_resolution(image.resolution_m)
    paint, params = paint or PaintParams(), params or ClassifyParams()
    rgb = rgb_of(image.pixels)
    hat = top_hat(brightness(rgb), image.resolution_m, image.valid, paint)
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
    res = image.resolution_m
    surface = road_surface(hsv, params.asphalt_saturation)
    mask = paint_mask(hat, paint) & near_road(surface, res)
    if road is not None:
        mask &= road
    found = classify(pieces(mask, res, params.min_length_m), hsv, hat, surface, res, params)
    lines = [m for m in found if m.kind in BOUNDING]
    zebras, bars = crossings([m for m in found if m.kind == "other"], lines, res)
    left = {id(m) for m in bars}
    return [m for m in found if m.kind != "other" or id(m) in left] + zebras


def markings_geojson(markings: list[Marking], image: Image) -> dict:
    """A FeatureCollection of LineStrings with kind, colour, width_m, length_m, confidence,
    pieces (dashes joined) and painted_share."""
    def out(coords: np.ndarray) -> list[list[float]]:
        if image.transform is None:
            return np.round(coords, 2).tolist()
        xs, ys = image.transform * (coords[:, 0], coords[:, 1])
        return np.column_stack([xs, ys]).round(9).tolist()

    features = [{
        "type": "Feature", "id": i,
        "geometry": {"type": "LineString", "coordinates": out(m.coords)},
        "properties": {"kind": m.kind, "colour": m.colour, "width_m": m.width_m,
                       "length_m": m.length_m, "confidence": m.confidence,
                       "pieces": m.pieces, "painted_share": m.painted_share},
    } for i, m in enumerate(markings)]
    return {"type": "FeatureCollection", **crs_member(image.crs, image.resolution_m),
            "features": features}
