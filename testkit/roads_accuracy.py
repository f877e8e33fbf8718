"""The accuracy protocol on labelled imagery: train on one quadrant, score on the other three.

Shared by ``tests/test_roads_real.py`` (which asserts measured floors) and
``bench/roads_accuracy.py`` (which prints the full table), so both measure the same thing.
The training quadrant is the one with the most labelled road (a user would also put the
sample where the roads are); its ground truth becomes the sample (road = 255, the rest 128).
Scores count only centerline pixels outside that quadrant, for every classifier, the
zero-shot road model included (it gets no sample at all), so all rows are comparable.
Connectivity (APLS, :mod:`ingest.roads.connectivity`) is measured on the same three quadrants.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import rasterio.features
import shapely
from shapely.geometry import LineString, shape
from shapely.geometry.base import BaseGeometry

from ingest.roads import RoadsInputError
from ingest.roads.classify import NOT_ROAD, ROAD
from ingest.roads.connectivity import apls
from ingest.roads.evaluate import (
    BufferScore,
    buffer_scores,
    distance_to_lines_m,
    line_pixels,
    rasterize_lines,
)
from ingest.roads.georef import Image, read_band, read_image
from ingest.roads.graph import GraphParams, build_graph
from ingest.roads.pipeline import Classifier, ExtractParams, extract_roads
from ingest.roads.skeleton import thin

APLS_SNAP_M = 5.0
"""A node of one graph matches the other graph within this distance (SpaceNet uses ~4 m)."""


@dataclass(frozen=True)
class Sample:
    """One labelled image under ``shared/data/road_imagery``."""

    name: str
    image: str
    truth: str
    """Mask image (road >= 128) or GeoJSON centerlines."""
    resolution_m: float | None
    """None: take it from the image's georeference."""


SAMPLES = (
    *(Sample(f"massachusetts_{n}", f"massachusetts/mass_{n}_sat.jpg",
             f"massachusetts/mass_{n}_label.jpg", 1.0) for n in ("01", "02", "04", "07")),
    *(Sample(f"deepglobe_{n}", f"deepglobe/{n}_sat.jpg", f"deepglobe/{n}_mask.png", 0.5)
      for n in ("104", "113", "343")),
    Sample("spacenet_vegas", "spacenet_vegas/RGB-PanSharpen_AOI_2_Vegas_img0.tif",
           "spacenet_vegas/AOI_2_Vegas_img0.geojson", None),
)



def holdout_samples(training_root: Path) -> list[Sample]:
    """The training set's model-selection scenes (:func:`ingest.roads.model.data.is_holdout`)
    as samples: pipeline settings are chosen on these, never on the validation images."""
    from ingest.roads.model.data import is_holdout

    pairs = json.loads((training_root / "pairs.json").read_text())
    return [Sample(Path(p["image"]).stem, p["image"], p["mask"], float(p["m_per_px"]))
            for p in pairs if is_holdout(p)]


CENTERLINE_ROAD_M = 3.0
"""For centerline ground truth: within this of a centerline the training sample says road..."""
CENTERLINE_CLEAR_M = 8.0
"""...and beyond this, not road (in between is left unlabelled)."""


def truth_rasters(sample: Sample, root: Path, image: Image
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[np.ndarray]]:
    """(road mask, scoring centerline, pixels too near a road to call "not road" or None,
    centerlines as pixel-coordinate polylines) on the image's pixel grid."""
    path = root / sample.truth
    if path.suffix != ".geojson":
        road = read_band(path)[0] >= 128
        centerline = thin(road)
        # The truth keeps the pixel geometry it was scored with before issue 20.
        graph = build_graph(centerline, road, image.resolution_m, GraphParams(geometry="pixel"))
        return road, centerline, None, [e.coords for e in graph.edges]
    if image.transform is None:
        raise RoadsInputError(f"{sample.image}: a GeoJSON truth needs a georeferenced image")
    lines = line_pixels(path, ~image.transform)
    centerline, metres = distance_to_lines_m(lines, image.pixels.shape[:2], image.resolution_m)
    road = metres <= CENTERLINE_ROAD_M
    return road, centerline, ~road & (metres <= CENTERLINE_CLEAR_M), lines


def quadrant_labels(road: np.ndarray, unsure: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(training labels, training region): the quadrant with the most road, labelled."""
    h, w = road.shape
    quads = [(slice(r, r + h // 2), slice(c, c + w // 2)) for r in (0, h // 2) for c in (0, w // 2)]
    best = max(quads, key=lambda q: int(road[q].sum()))
    region = np.zeros(road.shape, bool)
    region[best] = True
    labels = np.where(region, np.where(road, ROAD, NOT_ROAD), 0).astype(np.uint8)
    if unsure is not None:
        labels[unsure & region] = 0
    return labels, region


@dataclass(frozen=True)
class Truth:
    """A sample's ground truth on its image grid, and the quadrant the job trains on."""

    road: np.ndarray
    centerline: np.ndarray
    lines: list[np.ndarray]
    """Centerlines, source pixel-corner coordinates (the whole image)."""
    labels: np.ndarray
    """The training sample: the labelled quadrant."""
    region: np.ndarray
    """True in the training quadrant (not scored)."""
    resolution_m: float


def load_sample(sample: Sample, root: Path) -> tuple[Image, Truth]:
    """The sample's image and its ground truth."""
    image = read_image(root / sample.image, sample.resolution_m)
    road, centerline, unsure, truth_lines = truth_rasters(sample, root, image)
    labels, region = quadrant_labels(road, unsure)
    return image, Truth(road, centerline, truth_lines, labels, region, image.resolution_m)


@dataclass(frozen=True)
class Evaluation:
    """Scores of one classifier on one sample."""

    scores: list[BufferScore]
    """Buffer precision/recall, one per requested radius."""
    apls: float
    """Symmetric APLS on the scored quadrants."""
    seconds: float


def region_shape(region: np.ndarray) -> BaseGeometry:
    """The True pixels of ``region`` as one (multi)polygon in pixel-corner coordinates."""
    return shapely.union_all([shape(g) for g, _ in rasterio.features.shapes(
        region.astype(np.uint8), mask=region)])


def _clip_lines(lines: list[np.ndarray], cut: BaseGeometry, scale: float) -> list[np.ndarray]:
    """Polylines (pixels) minus what the sample labelled (``cut``), in metres."""
    out = []
    for line in lines:
        if len(line) < 2:
            continue
        rest = LineString(line).difference(cut)
        for part in getattr(rest, "geoms", [rest]):
            if not part.is_empty and part.length > 0:
                out.append(shapely.get_coordinates(part) * scale)
    return out


def score_lines(truth: Truth, pred_lines: list[np.ndarray], seconds: float = 0.0,
                radii_m: tuple[float, ...] = (1.0, 2.0)) -> Evaluation:
    """Buffer scores and APLS of predicted centerlines (source pixel-corner coordinates)
    outside the training quadrant."""
    pred = rasterize_lines(pred_lines, truth.road.shape)
    res = truth.resolution_m
    scores = buffer_scores(pred, truth.centerline, [r / res for r in radii_m], res,
                           region=~truth.region)
    # APLS on the graphs outside the labelled region itself: its bounding box was the whole
    # image for a sample of lines and boxes spread over it, and every APLS 0.
    cut = region_shape(truth.region)
    connectivity = apls(_clip_lines(truth.lines, cut, res),
                        _clip_lines(pred_lines, cut, res), snap_radius=APLS_SNAP_M)
    return Evaluation(scores, connectivity, seconds)


def evaluate_sample(sample: Sample, root: Path, classifier: Classifier,
                    radii_m: tuple[float, ...] = (1.0, 2.0),
                    params: ExtractParams | None = None) -> Evaluation:
    """Extract roads from ``sample`` with ``classifier`` and score them (see module doc)."""
    image, truth = load_sample(sample, root)
    params = replace(params or ExtractParams(), classifier=classifier)
    start = time.perf_counter()
    result = extract_roads(image, None if classifier == "model" else truth.labels, params)
    seconds = time.perf_counter() - start
    return score_lines(truth, result.source_lines(), seconds, radii_m)
