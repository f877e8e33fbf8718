"""The road-extraction pipeline: image (+ optional training labels) -> road graph.

Composition only; each stage lives in its own module. Images finer than the working
resolution are first averaged down to it: a road is metres wide, so 0.5-1 m pixels keep every
centerline within the survey's accuracy while a 0.16 m mosaic would cost 40 times the work.

Classifiers: ``model`` (the shipped road network, zero-shot, on its own 1 m grid),
``adapted`` (the same, adapted to the job's labels: :mod:`ingest.roads.model.adapt`),
``learned`` (per-job trees on hand-made features) and ``spectral`` (the survey's colour line).
The model paths keep the road probability, which the topology clean-up uses to decide which
gaps in the skeleton are real roads the threshold broke.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from skimage.filters import apply_hysteresis_threshold

from app.jobs.kinds import Classifier
from ingest.roads import RoadsInputError
from ingest.roads.classify import ROAD, learned_classify, spectral_classify
from ingest.roads.clean import clean_mask
from ingest.roads.georef import Frame, Image, crs_member, resize, to_working_grid
from ingest.roads.graph import GraphParams, RoadGraph, build_graph, feature_collection
from ingest.roads.houses import HouseRule, remove_houses
from ingest.roads.skeleton import prune_spurs, thin
from ingest.roads.topology import TopologyParams, clean_topology

MODEL_MAX_COARSER = 1.4
"""The model saw scales down to 1/1.4 in training: coarser pixels hide its roads."""


@dataclass(frozen=True)
class ExtractParams:
    """Every knob of the pipeline; sizes in metres."""

    classifier: Classifier = "auto"
    """``auto``: the road model, adapted to the sample when there is one."""
    k: float = 3.0
    """Spectral: keep pixels within k x the mean training distance to the colour line."""
    threshold: float = 0.5
    """Learned: road probability above which a pixel is road (model: its own threshold)..."""
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
    topology: TopologyParams = field(default_factory=TopologyParams)
    model_path: Path | None = None
    """ONNX road model; None = ``UGVMAP_ROAD_MODEL`` or the shipped ``models/roads-v1``."""


def tuned_params(classifier: Classifier | None = None, k: float | None = None,
                 work_resolution: float | None = None, spur_max: float | None = None,
                 simplify: float | None = None) -> ExtractParams:
    """The parameters from the tuning options of ``extract-roads`` / ``ingest roads`` (or a
    queued job's): None keeps the default, a ``work_resolution`` of 0 keeps the source grid."""
    params = ExtractParams()
    if classifier is not None:
        params = replace(params, classifier=classifier)
    if k is not None:
        params = replace(params, k=k)
    if spur_max is not None:
        params = replace(params, spur_max_m=spur_max)
    if work_resolution is not None:
        params = replace(params, work_resolution_m=work_resolution or None)
    if simplify is not None:
        params = replace(params, graph=replace(params.graph, simplify_m=simplify))
    return params


@dataclass(frozen=True)
class Extraction:
    """The graph, where it is, and every intermediate mask (for debugging and scoring)."""

    graph: RoadGraph
    frame: Frame
    classifier: str
    stages: dict[str, np.ndarray]
    source_resolution_m: float

    def geojson(self) -> dict:
        """The result as a GeoJSON FeatureCollection (map coordinates with a ``crs`` member when the
        image is georeferenced)."""
        return feature_collection(self.graph, self.frame,
                                  crs_member(self.frame.crs, self.source_resolution_m))

    def source_lines(self) -> list[np.ndarray]:
        """Edge geometries in source-image pixel-corner coordinates (for scoring)."""
        return [np.column_stack(self.frame.to_source @ (e.coords[:, 0], e.coords[:, 1]))
                for e in self.graph.edges]


def choose_classifier(requested: Classifier, labels: np.ndarray | None) -> str:
    """Resolve ``auto``: the road model, adapted when the user gave road labels."""
    if requested != "auto":
        return requested
    return "adapted" if labels is not None and (labels == ROAD).any() else "model"


def _on_grid(labels: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Source-grid labels on the working grid (nearest: a label is a class, not a value)."""
    if labels.shape == shape:
        return labels
    labels = resize(labels, shape, cv2.INTER_NEAREST)
    if not (labels == ROAD).any():
        raise RoadsInputError("the road sample is too small for the working grid: draw a "
                              "bigger --train-box (learned/spectral: or pass a finer "
                              "--work-resolution; the road model's grid is fixed)")
    return labels


def model_mask(image: Image, labels: np.ndarray | None, adapt: bool, params: ExtractParams,
               progress: bool = False) -> tuple[np.ndarray, np.ndarray, Frame]:
    """(road mask, road probability, frame) from the road model on its own grid."""
    from ingest.roads.model.adapt import adapted_probability
    from ingest.roads.model.data import rgb_bands, stretch, stretch_limits
    from ingest.roads.model.runtime import load_model, predict

    model = load_model(params.model_path)
    pixels, valid, frame = to_working_grid(image, model.resolution_m)
    if frame.resolution_m > model.resolution_m * MODEL_MAX_COARSER:
        raise RoadsInputError(
            f"the image is {frame.resolution_m:.2f} m/px but the road model works at "
            f"{model.resolution_m:g} m/px and cannot see roads in pixels coarser than "
            f"{model.resolution_m * MODEL_MAX_COARSER:g} m: use --classifier learned or "
            "spectral with a training sample")
    rgb = stretch(rgb_bands(pixels), stretch_limits(image.pixels, image.valid))
    del pixels
    if adapt:
        if labels is None:
            raise RoadsInputError("--classifier adapted needs a training sample (--train-box, "
                                  "--train-mask or --train-lines)")
        prob, _ = adapted_probability(model, rgb, _on_grid(labels, rgb.shape[:2]),
                                      frame.resolution_m, progress=progress)
        low = params.threshold
    else:
        prob, _ = predict(model, rgb, progress=progress)
        low = model.threshold
    binary = apply_hysteresis_threshold(prob, low, max(params.seed_threshold, low))
    if valid is not None:
        binary &= valid
    return binary, prob, frame


def extract_roads(image: Image, labels: np.ndarray | None = None,
                  params: ExtractParams = ExtractParams(), debug_dir: Path | None = None,
                  progress: bool = False) -> Extraction:
    """Run every stage; ``labels`` (255 road / 128 not road / 0) are on the source grid and
    optional for the road model (zero-shot)."""
    method = choose_classifier(params.classifier, labels)
    prob = None
    if method in ("model", "adapted"):
        binary, prob, frame = model_mask(image, labels, method == "adapted", params, progress)
    else:
        if labels is None:
            raise RoadsInputError(f"the {method} classifier needs a training sample: give "
                                  "--train-box, --train-mask or --train-lines")
        pixels, valid, frame = to_working_grid(image, params.work_resolution_m)
        labels = _on_grid(labels, pixels.shape[:2])
        if method == "learned":
            binary = learned_classify(pixels, labels, frame.resolution_m, params.threshold,
                                      params.seed_threshold, progress=progress)
        else:
            binary = spectral_classify(pixels, labels, params.k)
        del pixels
        if valid is not None:
            binary &= valid
    res = frame.resolution_m
    cleaned = clean_mask(binary, res, params.open_m, params.close_m, params.min_area_m2,
                         params.max_hole_m2)
    # Roof-like blobs are what colour classifiers confuse with roads; the network has learned
    # them, and the rectangle rule would cut its wide junctions and parking aisles.
    no_houses = cleaned if prob is not None else remove_houses(cleaned, params.houses)
    skeleton = prune_spurs(thin(no_houses), params.spur_max_m / res, params.spur_steps)
    stages = {"binary": binary, "cleaned": cleaned, "houses_removed": no_houses,
              "skeleton": skeleton}
    if prob is not None:
        skeleton = clean_topology(skeleton, prob, res, params.topology)
        stages["topology"] = skeleton
    graph = build_graph(skeleton, no_houses, res, params.graph)
    if debug_dir is not None:
        write_debug_images(stages, debug_dir)
        if prob is not None:
            cv2.imwrite(str(debug_dir / "0_probability.png"), np.round(prob * 255).astype(np.uint8))
    return Extraction(graph, frame, method, stages, image.resolution_m)


def write_debug_images(stages: dict[str, np.ndarray], debug_dir: Path) -> None:
    """One black/white PNG per stage, numbered in pipeline order."""
    debug_dir.mkdir(parents=True, exist_ok=True)
    for i, (name, mask) in enumerate(stages.items(), 1):
        path = debug_dir / f"{i}_{name}.png"
        if not cv2.imwrite(str(path), mask.astype(np.uint8) * 255):
            raise RoadsInputError(f"cannot write debug image {path}")
