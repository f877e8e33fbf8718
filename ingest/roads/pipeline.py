"""The road-extraction pipeline: image (+ optional training labels) -> road graph.

Composition only; each stage lives in its own module. Images finer than the working
resolution are first averaged down to it: a road is metres wide, so 0.5-1 m pixels keep every
centerline within the survey's accuracy while a 0.16 m mosaic would cost 40 times the work.

Classifiers: ``model`` (the shipped road network, zero-shot, on its own grid),
``adapted`` (the same, corrected by the job's labels: :mod:`ingest.roads.model.adapt`),
``learned`` (per-job trees on hand-made features) and ``spectral`` (the survey's colour line).
The model paths keep the road probability, which the topology clean-up uses to decide which
gaps in the skeleton are real roads the threshold broke.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from app.road_tuning import DEFAULT_TUNING, Classifier, RoadTuning
from ingest.roads import RoadsInputError
from ingest.roads.classify import ROAD, learned_classify, spectral_classify
from ingest.roads.clean import clean_mask
from ingest.roads.finegrid import applies, refine_on_source
from ingest.roads.georef import Frame, Image, crs_member, resize, to_working_grid
from ingest.roads.graph import GraphParams, RoadGraph, build_graph, feature_collection
from ingest.roads.houses import HouseRule, remove_houses
from ingest.roads.model.adapt import DEFAULT_ADAPT, AdaptParams
from ingest.roads.ridge import RoadField, soft_mask
from ingest.roads.skeleton import prune_spurs, thin
from ingest.roads.topology import TopologyParams, clean_topology

MODEL_MAX_COARSER = 2.5
"""How much coarser than the model's grid an image may be. Coarser images are enlarged to the
model's grid; roads-v2 (0.5 m) trained on 1 m imagery enlarged 2x and on crops degraded by up to
2.5x, so 1.2 m imagery works; beyond, roads are too few pixels wide to be found."""


@dataclass(frozen=True)
class ExtractParams:
    """Every knob of the pipeline; sizes in metres. The ones a user may set default to
    :data:`~app.road_tuning.DEFAULT_TUNING` (:func:`tuned_params` maps them here)."""

    classifier: Classifier = DEFAULT_TUNING.classifier
    """``auto``: the road model, adapted to the sample when there is one."""
    k: float = DEFAULT_TUNING.k
    """Spectral: keep pixels within k x the mean training distance to the colour line."""
    threshold: float = 0.5
    """Learned: road probability above which a pixel is road (the zero-shot model uses its
    own, chosen on its hold-out scenes; the adapted one its sample's)..."""
    seed_threshold: float = 0.85
    """...when connected to a pixel at least this probable (hysteresis; learned)."""
    work_resolution_m: float | None = DEFAULT_TUNING.work_resolution or None
    """Average finer images down to this grid; None keeps the source grid."""
    open_m: float = 1.0
    close_m: float = 2.0
    min_area_m2: float = 150.0
    max_hole_m2: float = 40.0
    model_open_m: float = 0.0
    """Road model paths: opening before thinning (``open_m`` is for the colour classifiers'
    speckle). The network's probability has none, and on imagery unlike its training a faint
    track is thresholded narrower than the road: a 1 m opening erased every road of a DeepGlobe
    tile. Chosen on the training hold-out scenes (``bench/roads_accuracy.py --holdout``: P/R at
    2 m 0.674/0.548 with 1 m, 0.673/0.551 without)."""
    model_min_area_m2: float = 20.0
    """Road model paths: smaller pieces are dropped (short ones go later, by length: an area
    rule would drop narrow roads first)."""
    houses: HouseRule = field(default_factory=HouseRule)
    spur_max_m: float = DEFAULT_TUNING.spur_max
    spur_steps: int = 4
    graph: GraphParams = field(default_factory=GraphParams)
    topology: TopologyParams = field(default_factory=TopologyParams)
    fine_max_m: float = 0.1
    """Sources this fine or finer (IPM mosaics) get their centrelines refined on their own
    grid (:mod:`ingest.roads.finegrid`); 0 switches that off."""
    model_path: Path | None = None
    """ONNX road model; None = ``UGVMAP_ROAD_MODEL`` or the shipped ``models/roads-v2``."""
    tta: int = 1
    """Road model: average it over this many rotations/mirrors of the image (1, 2, 4, 8)."""
    adapt: AdaptParams = DEFAULT_ADAPT
    """How the road model learns from a sample (:mod:`ingest.roads.model.adapt`)."""


def tuned_params(tuning: RoadTuning) -> ExtractParams:
    """The parameters from the user's tuning (``extract-roads`` / ``ingest roads`` options or a
    queued job's): a ``work_resolution`` of 0 keeps the source grid."""
    params = ExtractParams()
    return replace(params, classifier=tuning.classifier, k=tuning.k,
                   spur_max_m=tuning.spur_max, work_resolution_m=tuning.work_resolution or None,
                   graph=replace(params.graph, simplify_m=tuning.simplify))


@dataclass(frozen=True)
class Extraction:
    """The graph, where it is, and every intermediate mask (for debugging and scoring)."""

    graph: RoadGraph
    frame: Frame
    classifier: str
    stages: dict[str, np.ndarray]
    source_resolution_m: float
    sample_note: str | None = None
    """What the adapted model made of the sample
    (:meth:`ingest.roads.model.adapt.Adapted.summary`): whether it was used, and the held-out
    figures that decided it; ``None`` for other classifiers."""

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
    """Resolve ``auto``: the road model, adapted when the user labelled anything (a reviewer's
    deletions alone are "not road" labels, and worth learning from)."""
    if requested != "auto":
        return requested
    return "adapted" if labels is not None and labels.any() else "model"


def _on_grid(labels: np.ndarray, shape: tuple[int, int], need_road: bool = True) -> np.ndarray:
    """Source-grid labels on the working grid (nearest: a label is a class, not a value)."""
    if labels.shape == shape:
        return labels
    labels = resize(labels, shape, cv2.INTER_NEAREST)
    if need_road and not (labels == ROAD).any():
        raise RoadsInputError("the road sample is too small for the working grid: draw a "
                              "bigger --train-box (learned/spectral: or pass a finer "
                              "--work-resolution; the road model's grid is fixed)")
    return labels


def model_mask(image: Image, labels: np.ndarray | None, adapt: bool, params: ExtractParams,
               progress: bool = False) -> tuple[np.ndarray, RoadField, Frame, str | None]:
    """(road mask, road probability as a field, frame, what the sample did: ``None`` when
    zero-shot) from the road model on its own grid."""
    from ingest.roads.model.adapt import adapted_probability
    from ingest.roads.model.data import rgb_bands, stretch, stretch_limits
    from ingest.roads.model.runtime import load_model, predict

    model = load_model(params.model_path)
    if image.resolution_m > model.resolution_m * MODEL_MAX_COARSER:
        raise RoadsInputError(
            f"the image is {image.resolution_m:.2f} m/px but the road model works at "
            f"{model.resolution_m:g} m/px and cannot see roads in pixels coarser than "
            f"{model.resolution_m * MODEL_MAX_COARSER:g} m: use --classifier learned or "
            "spectral with a training sample")
    pixels, valid, frame = to_working_grid(image, model.resolution_m, upsample=True)
    rgb = stretch(rgb_bands(pixels), stretch_limits(image.pixels, image.valid))
    del pixels
    if adapt:
        if labels is None:
            raise RoadsInputError("--classifier adapted needs a training sample (--train-box, "
                                  "--train-mask or --train-lines)")
        adapted = adapted_probability(model, rgb, _on_grid(labels, rgb.shape[:2], False),
                                      params.adapt, progress=progress)
        prob, low, note = adapted.prob, adapted.threshold, adapted.summary()
        binary = prob >= low
    else:
        # Zero-shot: one cut, the model's own (hold-out F1) threshold. A second, absolute seed
        # level (0.85) held in the scenes the model knows and removed everything where it is
        # less sure, i.e. on imagery unlike its training. On the hold-out scenes (where it knows
        # the look) the two are equal in F1: P/R at 2 m with seeds 0.674/0.548, APLS 0.358;
        # one cut, no opening, 20 m² pieces 0.625/0.574, APLS 0.375 (roads-v2 at 6 epochs).
        prob, _ = predict(model, rgb, progress=progress, tta=params.tta)
        low, note = model.threshold, None
        binary = prob >= low
    if valid is not None:
        binary &= valid
    return binary, RoadField(prob, low, valid), frame, note


def extract_roads(image: Image, labels: np.ndarray | None = None,
                  params: ExtractParams = ExtractParams(), debug_dir: Path | None = None,
                  progress: bool = False) -> Extraction:
    """Run every stage; ``labels`` (255 road / 128 not road / 0) are on the source grid and
    optional for the road model (zero-shot)."""
    if image.valid is not None and not image.valid.any():
        raise RoadsInputError("the image has no data (every pixel is no-data or transparent): "
                              "nothing to extract roads from")
    if labels is not None and image.valid is not None:
        # A sample says nothing where the image has no data: "not road" burnt over a no-data
        # fill (a drive's sample labels everything far from the path, most of it unseen)
        # would teach the classifier that black is the only thing that is not road.
        labels = np.where(image.valid, labels, 0).astype(labels.dtype)
    method = choose_classifier(params.classifier, labels)
    field = None
    valid = None
    sample_note = None
    if method in ("model", "adapted"):
        binary, field, frame, sample_note = model_mask(image, labels, method == "adapted",
                                                       params, progress)
        valid = field.valid
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
    on_model = field is not None
    cleaned = clean_mask(binary, res, params.model_open_m if on_model else params.open_m,
                         params.close_m,
                         params.model_min_area_m2 if on_model else params.min_area_m2,
                         params.max_hole_m2)
    # Roof-like blobs are what colour classifiers confuse with roads; the network has learned
    # them, and the rectangle rule would cut its wide junctions and parking aisles.
    no_houses = cleaned if field is not None else remove_houses(cleaned, params.houses)
    skeleton = prune_spurs(thin(no_houses), params.spur_max_m / res, params.spur_steps)
    stages = {"binary": binary, "cleaned": cleaned, "houses_removed": no_houses,
              "skeleton": skeleton}
    if field is not None:
        skeleton = clean_topology(skeleton, field.values, res, params.topology, valid)
        stages["topology"] = skeleton
    else:
        field = RoadField(soft_mask(no_houses), 0.5, valid)
    graph = build_graph(skeleton, no_houses, res, params.graph, field)
    if params.graph.geometry == "ridge" and applies(image.resolution_m, res, params.fine_max_m):
        graph = refine_on_source(graph, image, frame.to_source, params.graph, params.k)
    if debug_dir is not None:
        write_debug_images(stages, debug_dir)
        if method in ("model", "adapted"):
            cv2.imwrite(str(debug_dir / "0_probability.png"),
                        np.round(field.values * 255).astype(np.uint8))
    return Extraction(graph, frame, method, stages, image.resolution_m, sample_note)


def write_debug_images(stages: dict[str, np.ndarray], debug_dir: Path) -> None:
    """One black/white PNG per stage, numbered in pipeline order."""
    debug_dir.mkdir(parents=True, exist_ok=True)
    for i, (name, mask) in enumerate(stages.items(), 1):
        path = debug_dir / f"{i}_{name}.png"
        if not cv2.imwrite(str(path), mask.astype(np.uint8) * 255):
            raise RoadsInputError(f"cannot write debug image {path}")
