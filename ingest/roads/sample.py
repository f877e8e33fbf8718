"""A training sample in map coordinates, and its label image on a raster's grid.

A layer has no pixel grid a user could point at, so samples are given in lon/lat: boxes and
areas that are or are not road, and lines along roads (drawn by a person, a vehicle's drive,
a segment a reviewer confirmed) or along what is not a road (a segment a reviewer deleted).
They are burnt into a 255 road / 128 not road / 0 unlabelled image on the raster's grid, on
valid pixels only (no-data is neither road nor not road).

Lines come in two kinds. Most are *some* of the roads (a person draws the few the model
missed): they say "road" along the line and nothing about the rest of the image. A drive's
trajectory or a file of every known road is *complete*: away from every line is "not road"
(``not_road_beyond_m``). Treating a partial sample as complete teaches the model that every
road nobody drew is background, which is what made labelled samples lower the score before.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely
from pyproj import CRS, Transformer
from rasterio.features import rasterize
from rasterio.transform import Affine
from shapely.geometry import box, shape
from shapely.geometry.base import BaseGeometry

from app.road_tuning import DEFAULT_SAMPLE_WIDTH
from ingest.roads import RoadsInputError
from ingest.roads.classify import NOT_ROAD, ROAD
from ingest.roads.georef import pixel_size_m

LonLatBox = tuple[float, float, float, float]
OPEN_END_M = 50.0
"""How far ahead of an open line end nothing is labelled "not road" (beyond a drive's view)."""
ROAD_EDGE_M = 6.0
"""A road line says where a road's middle is, not how wide it is: within this distance of it
a not-road *area* (a box or a painted polygon) says nothing, so a person who boxes an area and
draws every road in it labels the area completely without calling the roads' edges "not
road" (a 10 m road drawn as a 3 m band would teach the model 3.5 m of not road each side)."""


@dataclass(frozen=True)
class GeoSample:
    """Training sample in lon/lat (shapely geometries, boxes as min/max lon/lat)."""

    road_boxes: Sequence[LonLatBox] = ()
    not_road_boxes: Sequence[LonLatBox] = ()
    road_lines: Sequence[BaseGeometry] = ()
    """Centerlines of roads."""
    not_road_lines: Sequence[BaseGeometry] = ()
    """Lines along something that is not a road (a deleted false road)."""
    not_road_areas: Sequence[BaseGeometry] = ()
    """Polygons with no road in them."""
    line_width_m: float = DEFAULT_SAMPLE_WIDTH.line_width
    """Width of the band each line labels."""
    not_road_beyond_m: float | None = None
    """The road lines are every road there is: farther than this from all of them is "not
    road". None: the lines are some of the roads and say nothing about the rest."""
    open_ends: bool = False
    """The lines go on past their ends (a drive's trajectory): no "not road" ahead of them."""

    @property
    def empty(self) -> bool:
        """Nothing labelled at all."""
        return not (self.road_boxes or self.not_road_boxes or self.road_lines
                    or self.not_road_lines or self.not_road_areas)


def _extended(line: BaseGeometry, by: float) -> BaseGeometry:
    """A line continued straight past both ends by ``by`` (map units); other shapes as they are."""
    if not isinstance(line, shapely.LineString) or len(line.coords) < 2:
        return line
    xy = np.asarray(line.coords)
    ends = []
    for end, inner in ((xy[0], xy[1]), (xy[-1], xy[-2])):
        direction = end - inner
        ends.append(end + direction / max(float(np.hypot(*direction)), 1e-12) * by)
    return shapely.LineString(np.vstack([ends[0], xy, ends[1]]))


NO_SAMPLE_ROAD = ("the training sample does not cover any road pixel of the layer that has "
                  "data: check that the boxes / lines lie on the layer (lon/lat)")


def sample_labels(shape: tuple[int, int], to_map: Affine, crs: CRS, sample: GeoSample,
                  valid: np.ndarray | None = None) -> np.ndarray:
    """:func:`burn_sample`, refused when it labels nothing it was given (a sample off the
    image): a road sample must cover a road pixel, a not-road one some pixel."""
    labels = burn_sample(shape, to_map, crs, sample, valid)
    gives_road = bool(sample.road_lines or sample.road_boxes)
    if gives_road and not (labels == ROAD).any():
        raise RoadsInputError(NO_SAMPLE_ROAD)
    if not labels.any():
        raise RoadsInputError("the training sample does not cover any pixel of the layer that "
                              "has data: check that its areas / lines lie on the layer (lon/lat)")
    return labels


def burn_sample(shape: tuple[int, int], to_map: Affine, crs: CRS, sample: GeoSample,
                valid: np.ndarray | None = None) -> np.ndarray:
    """Burn a lon/lat training sample into a 255 road / 128 not road / 0 label image; pixels
    without data (``valid`` False) stay unlabelled, since no-data is neither.

    Widths are ground metres, turned into map units at the image (a web-mercator metre is
    1/cos(latitude) ground metres). Road wins where a road and a not-road label overlap: a
    person's road line crossing a painted area is the more specific statement, and the area
    says nothing within ``ROAD_EDGE_M`` of it (the road's edges).
    """
    transformer = Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    units_per_m = abs(to_map.a) / pixel_size_m(to_map, crs, shape)

    def projected(geom: BaseGeometry) -> BaseGeometry:
        return shapely.transform(geom, lambda xy: np.column_stack(
            transformer.transform(xy[:, 0], xy[:, 1])))

    def burn(geoms: list, value: int, labels: np.ndarray) -> None:
        geoms = [g for g in geoms if not g.is_empty]
        if geoms:
            rasterize([(g, value) for g in geoms], out=labels, transform=to_map)

    half = sample.line_width_m / 2 * units_per_m
    labels = np.zeros(shape, np.uint8)
    lines = [projected(g) for g in sample.road_lines]
    burn([projected(box(*b)) for b in sample.not_road_boxes]
         + [projected(g) for g in sample.not_road_areas], NOT_ROAD, labels)
    if lines and labels.any():
        edges = np.zeros(shape, np.uint8)
        burn([g.buffer(ROAD_EDGE_M * units_per_m) for g in lines], 1, edges)
        labels[edges == 1] = 0
    burn([projected(g).buffer(half) for g in sample.not_road_lines], NOT_ROAD, labels)
    if lines and sample.not_road_beyond_m is not None:
        beyond = sample.not_road_beyond_m * units_per_m
        near = np.zeros(shape, np.uint8)
        burn([(_extended(g, OPEN_END_M * units_per_m) if sample.open_ends else g).buffer(beyond)
              for g in lines], 1, near)
        labels[(near == 0) & (labels == 0)] = NOT_ROAD
    burn([projected(box(*b)) for b in sample.road_boxes], ROAD, labels)
    burn([g.buffer(half) for g in lines], ROAD, labels)
    if valid is not None:
        labels[~valid] = 0
    return labels


def given_sample(road_boxes: Sequence[LonLatBox], not_road_boxes: Sequence[LonLatBox],
                 lines_file: Path | None, line_width_m: float) -> GeoSample | None:
    """The sample a user gave ``ingest roads`` (on the command line or in a queued job), or
    None when they gave none (the road model then runs zero-shot). One place, so the command
    and the job cannot read the same options differently."""
    lines = _read_sample_lines(lines_file) if lines_file else []
    if not (road_boxes or not_road_boxes or lines):
        return None
    return GeoSample(road_boxes, not_road_boxes, lines, line_width_m=line_width_m,
                     not_road_beyond_m=3 * line_width_m)


def _read_sample_lines(path: Path) -> list[BaseGeometry]:
    """Road centerlines (lon/lat) from a GeoJSON file, as shapely geometries."""
    try:
        features = json.loads(path.read_text())["features"]
        return [shape(f["geometry"]) for f in features if f.get("geometry")]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise RoadsInputError(f"{path}: not a GeoJSON FeatureCollection of lines ({exc})") from exc
