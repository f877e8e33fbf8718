"""Per-job adaptation of the road model to a user's own labels, without torch.

The shipped network already separates roads from most clutter; what a new survey changes is
the look of its roads (dirt tracks, a sensor's colours, parking aisles that the job does or
does not want). Fine-tuning the network would need torch at run time, so instead a small
gradient-boosted classifier is trained on the labelled pixels with the network's own view of
them (its road probability as a logit and its 16 decoder features) next to the hand-made
multi-scale features of :mod:`ingest.roads.classify`. Where the network is right the trees
learn to follow its logit; where the job's labels disagree, they learn the exception.

A sample with road labels only (a ``--train-box`` around a road) gets pseudo not-road labels
where the network is confidently not road *and* the colour is unlike the sampled road (the
survey's spectral line, :func:`ingest.roads.classify.spectral_classify`): on imagery the
network does not know, its "not road" covers the very roads the user pointed at, and those
must not be taught as negatives.
"""

from __future__ import annotations

import numpy as np

from ingest.roads.classify import (
    NOT_ROAD,
    ROAD,
    UNLABELLED,
    road_probability,
    spectral_classify,
    train_pixel_classifier,
)
from ingest.roads.model.runtime import RoadModel, predict

PSEUDO_NOT_ROAD_BELOW = 0.05
"""Network probability under which an unlabelled pixel may serve as a not-road example."""


def model_features(prob: np.ndarray, features: np.ndarray) -> np.ndarray:
    """(rows, cols, 1 + C): the probability as a clipped logit, then the decoder features."""
    p = np.clip(prob, 1e-4, 1 - 1e-4)
    logit = np.log(p / (1 - p)).astype(np.float32)
    return np.concatenate([logit[..., None], features], axis=-1)


def with_pseudo_labels(labels: np.ndarray, prob: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """``labels`` plus not-road where unlabelled, the network is sure and the colour is not
    the sampled road's, if the sample has no not-road of its own."""
    if (labels == NOT_ROAD).any():
        return labels
    out = labels.copy()
    road_coloured = spectral_classify(rgb, labels)
    out[(labels == UNLABELLED) & (prob < PSEUDO_NOT_ROAD_BELOW) & ~road_coloured] = NOT_ROAD
    return out


def adapted_probability(model: RoadModel, rgb: np.ndarray, labels: np.ndarray,
                        resolution_m: float, progress: bool = False
                        ) -> tuple[np.ndarray, np.ndarray]:
    """(adapted road probability, the network's own probability) on the model grid."""
    prob, feats = predict(model, rgb, features=True, progress=progress)
    assert feats is not None  # asked for
    extra = model_features(prob, feats)
    del feats
    labels = with_pseudo_labels(labels, prob, rgb)
    if not ((labels == ROAD).any() and (labels == NOT_ROAD).any()):
        return prob, prob
    trees = train_pixel_classifier(rgb, labels, resolution_m, extra=extra)
    return road_probability(rgb, trees, resolution_m, progress=progress, extra=extra), prob
