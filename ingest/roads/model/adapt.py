"""Per-job adaptation of the road model to a user's own labels, without torch.

The shipped network already separates roads from most clutter; what a new survey changes is
the look of its roads (dirt tracks, a sensor's colours, parking aisles that the job does or
does not want). Fine-tuning the network would need torch at run time, so instead a small
gradient-boosted classifier is trained on the labelled pixels with the network's own view of
them (its road probability as a logit and its 16 decoder features) next to the hand-made
multi-scale features of :mod:`ingest.roads.classify`. Where the network is right the trees
learn to follow its logit; where the job's labels disagree, they learn the exception.

A sample with road labels only (a ``--train-box`` around a road) gets pseudo not-road labels
where the network is confidently not road, so adaptation never needs more than it has.
"""

from __future__ import annotations

import numpy as np

from ingest.roads.classify import (
    NOT_ROAD,
    ROAD,
    UNLABELLED,
    road_probability,
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


def with_pseudo_labels(labels: np.ndarray, prob: np.ndarray) -> np.ndarray:
    """``labels`` plus not-road where unlabelled and the network is sure, if none was given."""
    if (labels == NOT_ROAD).any():
        return labels
    out = labels.copy()
    out[(labels == UNLABELLED) & (prob < PSEUDO_NOT_ROAD_BELOW)] = NOT_ROAD
    return out


def adapted_probability(model: RoadModel, rgb: np.ndarray, labels: np.ndarray,
                        resolution_m: float, progress: bool = False
                        ) -> tuple[np.ndarray, np.ndarray]:
    """(adapted road probability, the network's own probability) on the model grid."""
    prob, feats = predict(model, rgb, features=True, progress=progress)
    extra = model_features(prob, feats)
    del feats
    labels = with_pseudo_labels(labels, prob)
    if not ((labels == ROAD).any() and (labels == NOT_ROAD).any()):
        return prob, prob
    trees = train_pixel_classifier(rgb, labels, resolution_m, extra=extra)
    return road_probability(rgb, trees, resolution_m, progress=progress, extra=extra), prob
