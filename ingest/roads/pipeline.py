"""The road-extraction pipeline: image + training labels -> road graph (+ debug images).

Composition only; each stage lives in its own module. Images finer than the working
resolution are first averaged down to it: a road is metres wide, so 0.5 m pixels keep every
centerline within the survey's accuracy while a 0.16 m mosaic would cost ten times the work.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from ingest.roads import RoadsInputError
from ingest.roads.classify import NOT_ROAD, ROAD, learned_classify, spectral_classify
from ingest.roads.clean import clean_mask
from ingest.roads.georef import Frame, Image, crs_member, resize, to_working_grid
from ingest.roads.graph import GraphParams, RoadGraph, build_graph, feature_collection
from ingest.roads.houses import HouseRule, remove_houses
from ingest.roads.skeleton import prune_spurs, thin

Classifier = Literal["auto", "spectral", "learned"]


@dataclass(frozen=True)
class ExtractParams:
    """Every knob of the pipeline; sizes in metres."""

    classifier: Classifier = "auto"
    """``auto``: learned when the sample has not-road labels, else spectral."""
    k: float = 3.0
    """Spectral: keep pixels within k x the mean training distance to the colour line."""
    threshold: float = 0.5
    """Learned: road probability above which a pixel is road..."""
    seed_threshold: float = 0.85
    """...when connected to a pixel at least this probable (hysteresis)."""
    work_resolution_m: float | None = 0.5
    """Average finer images down to this grid; None keeps the source grid."""
    open_m: float = 1.0
    close_m: float = 2.0
    min_area_m2: float = 150.0
    max_hole_m2: float = 40.0
    houses: HouseRule = field(default_factory=HouseRule)
    spur_max_m: float = 15.0
    spur_steps: int = 4
    graph: GraphParams = field(default_factory=GraphParams)


@dataclass(frozen=True)
class Extraction:
    """The graph, where it is, and every intermediate mask (for debugging and scoring)."""

    graph: RoadGraph
    frame: Frame
    classifier: str
    stages: dict[str, np.ndarray]
    source_resolution_m: float

    def geojson(self) -> dict:
        return feature_collection(self.graph, self.frame,
                                  crs_member(self.frame.crs, self.source_resolution_m))

    def source_lines(self) -> list[np.ndarray]:
        """Edge geometries in source-image pixel-corner coordinates (for scoring)."""
        return [np.column_stack(self.frame.to_source @ (e.coords[:, 0], e.coords[:, 1]))
                for e in self.graph.edges]


def choose_classifier(requested: Classifier, labels: np.ndarray) -> str:
    """Resolve ``auto``: the learned classifier needs not-road examples."""
    if requested != "auto":
        return requested
    return "learned" if (labels == NOT_ROAD).any() else "spectral"


def extract_roads(image: Image, labels: np.ndarray, params: ExtractParams = ExtractParams(),
                  debug_dir: Path | None = None, progress: bool = False) -> Extraction:
    """Run every stage; ``labels`` (255 road / 128 not road / 0) are on the source grid."""
    pixels, valid, frame = to_working_grid(image, params.work_resolution_m)
    if labels.shape != pixels.shape[:2]:
        labels = resize(labels, pixels.shape[:2], cv2.INTER_NEAREST)
        if not (labels == ROAD).any():
            raise RoadsInputError("the road sample is too small for the working grid: draw a "
                                  "bigger --train-box or pass a finer --work-resolution")
    res = frame.resolution_m
    method = choose_classifier(params.classifier, labels)
    if method == "learned":
        binary = learned_classify(pixels, labels, res, params.threshold, params.seed_threshold,
                                  progress=progress)
    else:
        binary = spectral_classify(pixels, labels, params.k)
    if valid is not None:
        binary &= valid
    cleaned = clean_mask(binary, res, params.open_m, params.close_m, params.min_area_m2,
                         params.max_hole_m2)
    no_houses = remove_houses(cleaned, params.houses)
    skeleton = prune_spurs(thin(no_houses), params.spur_max_m / res, params.spur_steps)
    graph = build_graph(skeleton, no_houses, res, params.graph)
    stages = {"binary": binary, "cleaned": cleaned, "houses_removed": no_houses,
              "skeleton": skeleton}
    if debug_dir is not None:
        write_debug_images(stages, debug_dir)
    return Extraction(graph, frame, method, stages, image.resolution_m)


def write_debug_images(stages: dict[str, np.ndarray], debug_dir: Path) -> None:
    """One black/white PNG per stage, numbered in pipeline order."""
    debug_dir.mkdir(parents=True, exist_ok=True)
    for i, (name, mask) in enumerate(stages.items(), 1):
        path = debug_dir / f"{i}_{name}.png"
        if not cv2.imwrite(str(path), mask.astype(np.uint8) * 255):
            raise RoadsInputError(f"cannot write debug image {path}")
