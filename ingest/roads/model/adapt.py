"""Adapting the road model to a map team's labels in seconds, without torch at run time.

The shipped network already separates roads from most clutter; what a new survey changes is
which look-alikes count (parking aisles, field tracks, canals) and how its roads look. So the
network stays frozen and a small *correction* is learnt on top of it: the adapted road logit
is the network's own logit plus a function of the network's 16 decoder features, the principal
components of its pretrained encoder's context (what tells a survey's roads from their
look-alikes is often only there: the decoder kept what its training scenes needed), its logit
blurred at two scales (is there road around here) and the pixel's colour, regularised towards
zero. With few labels the correction stays near zero and the result is close to the
zero-shot one; with many it learns where the team disagrees with the network. The earlier
per-job trees, learnt from scratch on the labelled pixels, scored below zero-shot with a whole
labelled quadrant; this correction scores above it on every validation image (the model
card's "Adaptation").

Labels a person gives are not a random sample of the image: a reviewer deletes the network's
false roads (all of them confidently "road" to the network) and draws the ones it missed (all
confidently "not road"). Learnt from those alone, a correction inverts the network. Every
unlabelled pixel is therefore an *anchor* whose target is the network's own probability: it
costs nothing where the correction leaves it alone and resists every change there, so the
correction must keep what nobody contradicted, in proportion to how much of the image that is.
Where a person labelled every pixel of an area, road and not road, that area is a fair sample
and the anchors nearly step aside (``complete_anchor_weight``).

The correction is learnt on half of the image's blocks and judged by the labels of the other
half: that chooses the threshold of the adapted probability (never below the network's own),
and where the judged half agrees with the labels not clearly better than the network alone
(contradictory labels, too few to learn from, a review's labels that the network gets all wrong
either way) the network's own result stands. Where a person labelled "not road", nothing is
drawn.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import minimize

from ingest.roads.classify import NOT_ROAD, ROAD
from ingest.roads.model.runtime import RoadModel, predict, quarter
from ingest.roads.sample import ROAD_EDGE_M


@dataclass(frozen=True)
class AdaptParams:
    """The knobs of the correction (chosen on ``bench/roads_adapt.py``; see docs/roads.md)."""

    context_px: tuple[float, ...] = (2.0, 6.0)
    """Gaussian scales (model-grid pixels) at which the network's logit is also given."""
    smooth_px: float = 3.0
    """Gaussian scale (model-grid pixels) every feature is blurred by before the correction."""
    hidden: int = 0
    """0: a linear correction; > 0: a one-hidden-layer (tanh) correction of that width."""
    l2: float = 1.0
    """Weight decay of the correction (weights count thousands of pixels)."""
    pixels: int = 30_000
    """Labelled pixels the correction learns from (a uniform draw keeps the sample's mix)."""
    anchors: int = 20_000
    """Unlabelled pixels that hold the correction to the network's own opinion..."""
    anchor_weight: float = 0.5
    """...each weighing this much of a labelled pixel, where the labels are partial (lines,
    strokes, a review's deletions: chosen by the network's mistakes)..."""
    complete_anchor_weight: float = 0.01
    """...and this much where they are complete (every pixel of an area labelled, road and
    not road: a random sample of what the team wants, which the network's opinion must not
    outvote; with the encoder's context and 0.5, a labelled quadrant's F1 was 0.38-0.78 on
    DeepGlobe and Vegas, with 0.01 0.47-0.81, while a review's fell 0.74-0.81 -> 0.21-0.62
    with 0.01)."""
    complete_share: float = 0.6
    """A block is completely labelled when this share of its pixels is labelled or lies within
    ``complete_edge_m`` of a road label..."""
    complete_edge_m: float = ROAD_EDGE_M
    """...(a boxed area whose roads are drawn as lines leaves their edges unlabelled: 6 m
    each side of a line, :data:`ingest.roads.sample.ROAD_EDGE_M`)..."""
    complete_not_road: float = 0.1
    """...and at least this share of it is labelled not road (an area: a 3 m deleted line
    across a 32 m block is 9 %)..."""
    complete_min_blocks: int = 9
    """...in a connected area of at least this many blocks (about 100 m square: three 40 m
    boxes beside a person's road lines are not a labelled area)."""
    context_from: float = 0.5
    """The encoder's context is read where at least this share of the sample labels whole
    areas (:func:`completeness`). Strokes and reviews label what the network got wrong, or
    the middle of clear roads; the context's freedom fits that selection instead of the
    roads (DeepGlobe 113's review: F1 0.761 -> 0.654 with it, 0.775 without)."""
    context_components: int = 24
    """The encoder context's 176 channels are reduced to this many principal components of
    the image's own (the fit's cost grows with the square of its inputs: 3.4 s with all of
    them on a DeepGlobe tile)."""
    block_px: int = 64
    """Side of the blocks (model-grid pixels: 32 m) the sample is split by to choose the
    threshold, and judged complete in (:func:`completeness`)."""
    gate_margin: float = 0.02
    """How much better (in F1 on the held-out half's labels) than the network alone the trial
    correction must agree with them to be used. A review's labels all lie where the network
    was wrong, so the network agrees with them at ~0 and any correction "improves" on that:
    DeepGlobe 113's review went 0.004 -> 0.008 and its extraction F1 0.761 -> 0.673."""


DEFAULT_ADAPT = AdaptParams()


def _blur(a: np.ndarray, sigma: float) -> np.ndarray:
    return cv2.GaussianBlur(a, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)


def logit_of(prob: np.ndarray) -> np.ndarray:
    """The network's probability as a clipped logit (float32)."""
    p = np.clip(prob, 1e-4, 1 - 1e-4)
    return np.log(p / (1 - p)).astype(np.float32)


def correction_features(logit: np.ndarray, features: np.ndarray, rgb: np.ndarray,
                        context_px: tuple[float, ...], smooth_px: float) -> np.ndarray:
    """(C, rows, cols) what the correction sees: decoder features, blurred logits and colour
    (all channels first, as :func:`predict` gives the features), each with its linear
    dependence on the logit taken out.

    The network's logit is a linear function of its decoder features, so a linear correction
    of them could simply scale the logit down or invert it, and labels chosen by the network's
    mistakes (deleted false roads, all "sure", drawn missed ones, all "unsure") teach exactly
    that: the result had hollow roads and drew their edges. Without the logit's direction the
    correction can only add what the network did not already say. Every feature is also
    blurred (``smooth_px``), so the correction is smooth across a road: it raises or lowers a
    whole road, never its middle against its edges (which thinning then splits in two)."""
    channels = [*features, *(_blur(logit, s) for s in context_px), *rgb]
    x = np.empty((len(channels), *logit.shape), np.float32)
    for i, channel in enumerate(channels):
        x[i] = _blur(np.ascontiguousarray(channel, dtype=np.float32), smooth_px)
    flat_x, flat_logit = x.reshape(len(channels), -1), logit.ravel()
    some = np.random.default_rng(0).choice(len(flat_logit), min(len(flat_logit), 200_000),
                                           replace=False)
    centred = flat_logit[some] - flat_logit[some].mean()
    seen = flat_x[:, some]
    slope = ((seen - seen.mean(axis=1, keepdims=True)) @ centred) / max(
        float(centred @ centred), 1e-12)
    for i, s in enumerate(slope.astype(np.float32)):
        flat_x[i] -= flat_logit * s
    return x


def principal_components(x: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """(k, rows, cols) the ``k`` principal components of the image's channels ``x`` (C, rows,
    cols), each channel standardised first (found on at most 20,000 pixels: the axes of a
    few hundred thousand agree to the third decimal)."""
    flat = x.reshape(x.shape[0], -1)
    some = np.random.default_rng(seed).choice(flat.shape[1], min(flat.shape[1], 20_000),
                                              replace=False)
    seen = flat[:, some].astype(np.float64)
    mean, scale = seen.mean(axis=1), seen.std(axis=1) + 1e-6
    standard = (seen - mean[:, None]) / scale[:, None]
    # The axes are the covariance's eigenvectors: 176 x 176, over 10x faster than an SVD of the
    # pixels themselves, the largest eigenvalues last.
    _, vectors = np.linalg.eigh(standard @ standard.T)
    project = (vectors[:, ::-1][:, :k].T / scale).astype(np.float32)
    return (project @ flat - (project @ mean)[:, None]).reshape(-1, *x.shape[1:])


@dataclass(frozen=True)
class Correction:
    """A learnt correction of the network's logit: standardisation and weights."""

    mean: np.ndarray
    scale: np.ndarray
    weights: tuple[np.ndarray, ...]
    """(w, b) for a linear correction, (W1, b1, w2, b2) for a hidden layer."""

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """The correction (added to the logit) for rows of features ``x`` (n, C)."""
        return self.of_channels(x.T)

    def of_channels(self, x: np.ndarray) -> np.ndarray:
        """The correction for features ``x`` (C, n), channels first as a whole image's are:
        the standardisation is folded into the first weights, so the image is read once by
        one matrix product and never copied."""
        w0 = self.weights[0]
        first = w0 / (self.scale if w0.ndim == 1 else self.scale[:, None])
        bias = self.weights[1] - self.mean @ first
        if len(self.weights) == 2:
            return first @ x + bias
        w2, b2 = self.weights[2:]
        hidden = first.T @ x + bias[:, None]
        return w2 @ np.tanh(hidden, out=hidden) + b2


def _unpack(theta: np.ndarray, shapes: list[tuple[int, ...]]) -> list[np.ndarray]:
    out, i = [], 0
    for shape in shapes:
        n = int(np.prod(shape)) if shape else 1
        out.append(theta[i:i + n].reshape(shape))
        i += n
    return out


def fit_correction(x: np.ndarray, offset: np.ndarray, y: np.ndarray, weight: np.ndarray,
                   params: AdaptParams, seed: int = 0) -> Correction:
    """Weighted logistic regression of ``y`` on ``offset`` + correction(``x``), by Newton
    steps (a trust region) when it is linear and L-BFGS with a hidden layer, the
    correction's weights decayed towards 0 (so no evidence means no change)."""
    mean = x.mean(axis=0)
    scale = x.std(axis=0) + 1e-6
    # float64 once: every product with the float64 weights would otherwise cast it again.
    xs = ((x - mean) / scale).astype(np.float64)
    offset = offset.astype(np.float64)
    c, h = x.shape[1], params.hidden
    shapes: list[tuple[int, ...]] = [(c, h), (h,), (h,), ()] if h else [(c,), ()]
    rng = np.random.default_rng(seed)
    theta0 = np.concatenate([rng.normal(0, 0.1, c * h), np.zeros(2 * h + 1)]) if h else \
        np.zeros(c + 1)
    l2 = params.l2

    def loss(theta: np.ndarray) -> tuple[float, np.ndarray]:
        parts = _unpack(theta, shapes)
        if h:
            w1, b1, w2, b2 = parts
            hid = np.tanh(xs @ w1 + b1)
            z = offset + hid @ w2 + b2
        else:
            w, b = parts
            z = offset + xs @ w + b
        p = 1 / (1 + np.exp(-z))
        g = weight * (p - y)
        value = float(np.sum(weight * (np.logaddexp(0, z) - y * z)))
        if h:
            gh = np.outer(g, w2) * (1 - hid ** 2)
            grads = [xs.T @ gh + 2 * l2 * w1, gh.sum(0), hid.T @ g + 2 * l2 * w2,
                     np.array(g.sum())]
            value += l2 * float(np.sum(w1 ** 2) + np.sum(w2 ** 2))
        else:
            grads = [xs.T @ g + 2 * l2 * w, np.array(g.sum())]
            value += l2 * float(np.sum(w ** 2))
        return value, np.concatenate([np.ravel(a) for a in grads])

    def hessian(theta: np.ndarray) -> np.ndarray:
        """The linear correction's exact Hessian: the loss is convex there, and Newton steps
        reach its minimum in ~10 evaluations where L-BFGS took ~90 (0.9 s on 50,000 pixels)."""
        w, b = _unpack(theta, shapes)
        p = 1 / (1 + np.exp(-(offset + xs @ w + b)))
        curvature = weight * p * (1 - p)
        out = np.empty((c + 1, c + 1))
        # A^T A of one array is one symmetric product (BLAS syrk): a third faster than
        # (X * curvature)^T X, and each fit takes ~7 of these.
        root = xs * np.sqrt(curvature)[:, None]
        out[:c, :c] = root.T @ root + 2 * l2 * np.eye(c)
        out[:c, c] = out[c, :c] = curvature @ xs
        out[c, c] = curvature.sum()
        return out

    if h:
        result = minimize(loss, theta0, jac=True, method="L-BFGS-B", options={"maxiter": 200})
    else:
        result = minimize(loss, theta0, jac=True, hess=hessian, method="trust-exact")
    weights = tuple(_unpack(result.x, shapes))
    return Correction(mean.astype(np.float32), scale.astype(np.float32),
                      tuple(a.astype(np.float32) for a in weights))


def completeness(labels: np.ndarray, params: AdaptParams, resolution_m: float) -> float:
    """The share (0..1) of labelled pixels (on a grid of ``resolution_m``) that lie in
    completely labelled areas: at least ``complete_min_blocks`` connected blocks of
    ``block_px``, each covered over ``complete_share`` of its area and ``complete_not_road``
    of it labelled not road, that together hold both road and not road. A not-road box alone
    says nothing about how roads look, and strokes, a review's lines or a few small boxes
    beside them never fill such an area.

    A pixel within ``complete_edge_m`` of a road label counts as covered: a road's edges are
    left unlabelled on purpose (a road line's 6 m, :data:`ingest.roads.sample.ROAD_EDGE_M`;
    the 2-6 m band a centreline truth cannot call either), and in a town, where a 32 m block
    holds two streets, those edges alone took SpaceNet Vegas's labelled quadrant under 60 % of
    its blocks, so the most complete sample there was read as strokes (completeness 0.28;
    0.93 with the edges). Counting the edges, a person's five road lines beside three 40 m
    boxes came out 0.63 complete on Vegas, and a review's 145 drawn streets 0.29 on
    Massachusetts 02: the not-road share of a block (an area, not a 3 m deleted line) and the
    size of the area keep those out (0.00 on every validation image)."""
    block = params.block_px
    rows, cols = labels.shape
    pad = ((0, -rows % block), (0, -cols % block))
    said = np.pad(labels != 0, pad)
    road = np.pad(labels == ROAD, pad)
    covered = said
    if road.any():
        edge_px = params.complete_edge_m / resolution_m
        covered = said | (cv2.distanceTransform((~road).astype(np.uint8), cv2.DIST_L2, 3)
                          <= edge_px)
    shape = (said.shape[0] // block, block, said.shape[1] // block, block)

    def per_block(mask: np.ndarray) -> np.ndarray:
        return mask.reshape(shape).sum(axis=(1, 3))

    said_in, road_in = per_block(said), per_block(road)
    full = ((per_block(covered) >= params.complete_share * block * block)
            & (said_in - road_in >= params.complete_not_road * block * block)).astype(np.uint8)
    count, area = cv2.connectedComponents(full, connectivity=8)
    complete = 0
    for k in range(1, count):
        blocks = area == k
        roads, labelled = road_in[blocks].sum(), said_in[blocks].sum()
        if blocks.sum() >= params.complete_min_blocks and 0 < roads < labelled:
            complete += int(labelled)
    return complete / max(int(said.sum()), 1)


def training_pixels(labels: np.ndarray, prob: np.ndarray, params: AdaptParams,
                    complete: float, within: np.ndarray | None = None, seed: int = 0
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(flat pixel indices, targets in 0..1, weights in thousands of pixels): labelled pixels
    (target 0 or 1) and anchors (unlabelled pixels, target the network's own probability),
    each drawn uniformly and weighed by how many pixels it stands for, an anchor
    ``anchor_weight`` of a labelled pixel (``complete_anchor_weight`` in the share
    ``complete`` of the sample that labels whole areas, :func:`completeness`); only pixels
    ``within`` (flat) if given.

    An anchor's target is what the uncorrected model already says, so it pulls nothing
    towards itself and only resists change: the correction pays for every unlabelled pixel it
    moves. Weighed by the pixels they stand for, a fully labelled quadrant outweighs that
    resistance, while thirty deleted false roads (a thin band each) or five drawn roads cannot
    move the whole image."""
    rng = np.random.default_rng(seed)
    flat = labels.ravel()
    inside = np.ones(flat.shape, bool) if within is None else within
    labelled = np.flatnonzero(inside & ((flat == ROAD) | (flat == NOT_ROAD)))
    picked = rng.choice(labelled, min(len(labelled), params.pixels), replace=False)
    free = np.flatnonzero(inside & (flat == 0))
    anchors = rng.choice(free, min(len(free), params.anchors), replace=False)
    anchor_weight = (1 - complete) * params.anchor_weight + \
        complete * params.complete_anchor_weight
    index = np.concatenate([picked, anchors])
    target = np.concatenate([(flat[picked] == ROAD).astype(np.float64),
                             prob.ravel()[anchors].astype(np.float64)])
    weight = np.concatenate([
        np.full(len(picked), len(labelled) / max(len(picked), 1)),
        np.full(len(anchors), anchor_weight * len(free) / max(len(anchors), 1))])
    return index, target, weight / 1000.0


CUTS = np.linspace(0.1, 0.9, 17)
"""The thresholds a sample may choose between."""


def weighted_f1(prob: np.ndarray, road: np.ndarray, weight: np.ndarray, cut: float) -> float:
    """F1 of ``prob >= cut`` against ``road``, each pixel counting ``weight``."""
    said = prob >= cut
    tp = weight[road & said].sum()
    return float(2 * tp / max(2 * tp + weight[~road & said].sum() + weight[road & ~said].sum(),
                              1e-12))


def agreement(prob: np.ndarray, road: np.ndarray, weight: np.ndarray, cut: float) -> float:
    """How well ``prob >= cut`` agrees with labels: weighted F1 when they hold both classes,
    else the weighted share it gets right (a reviewer's deletions alone are all "not road")."""
    if road.any() and not road.all():
        return weighted_f1(prob, road, weight, cut)
    return float(weight[(prob >= cut) == road].sum() / max(weight.sum(), 1e-12))


def best_threshold(prob: np.ndarray, road: np.ndarray, weight: np.ndarray, default: float,
                   margin: float = 0.01) -> float:
    """The cut from ``default`` to 0.9 with the best weighted F1, if it beats ``default`` by
    more than ``margin``; else ``default`` (one class, or labels every cut separates alike,
    say nothing about where to cut). Never below ``default``: a person's lines label the
    middle of clear roads, where a lower cut always looks better, and drew false roads
    everywhere else (a person's sample at 0.1: Massachusetts 01 P 0.72 -> 0.54)."""
    if road.all() or not road.any():
        return default
    cuts = CUTS[np.greater_equal(CUTS, default)]
    scores = [weighted_f1(prob, road, weight, c) for c in cuts]
    best = int(np.argmax(scores))
    if scores[best] <= weighted_f1(prob, road, weight, default) + margin:
        return default
    return float(cuts[best])


@dataclass(frozen=True)
class Adapted:
    """What a sample made of the network's road probability, and whether it was used.

    A person who drew roads must learn when their sample changed nothing (the network's own
    result, their "not road" areas removed): otherwise the same lines come back and they
    cannot tell a sample that was judged and turned away from one that was never read."""

    prob: np.ndarray
    """The road probability to cut (the network's own where the sample was not used; 0 where
    a person said "not road" either way)."""
    network: np.ndarray
    """The network's own probability."""
    threshold: float
    used: bool
    """Whether the correction learnt from the sample was applied (it agreed with the held-out
    half of the labels better than the network by ``gate_margin``)."""
    held_network: float
    """The network's agreement (F1, or share right for one class) with the held-out labels."""
    held_adapted: float
    """The trial correction's agreement with them."""
    margin: float
    """How much better than the network it had to be (``AdaptParams.gate_margin``)."""

    def summary(self) -> str:
        """One line for a person: used or not, and the held-out figures that decided it."""
        scores = (f"on the held-out half of the labels the adapted model agreed "
                  f"{self.held_adapted:.2f} and the network {self.held_network:.2f}")
        if self.used:
            return f"sample used: {scores}"
        return (f"sample not used: {scores}, not better by {self.margin:g}, so this is the "
                "network's own result (its \"not road\" areas removed); label roads it misses "
                "and its false ones to teach it")


def adapted_probability(model: RoadModel, rgb: np.ndarray, labels: np.ndarray,
                        params: AdaptParams = DEFAULT_ADAPT, progress: bool = False
                        ) -> Adapted:
    """The road probability on the model grid adapted to ``labels`` (255 road / 128 not road
    / 0) on the same grid.

    The correction is first learnt on half of the image's blocks and judged on the other
    half, labels and anchors alike: that chooses the threshold, and where the held-out half
    is not clearly better than the network on its own (``gate_margin``: contradictory labels,
    too few to learn from, or labels the network gets all wrong either way), the network's own
    probability and threshold are returned unchanged.

    The correction is computed at a quarter of the model grid's resolution (2 m), as the
    network's features come (:func:`predict`: the encoder's context is native there), and
    added to the full-resolution logit resampled: everything it sees is blurred by
    ``smooth_px`` (1.5 m) first, so it is smooth at that scale anyway, and the 190-odd
    channels of a 3000 px grid take 430 MB there (1.7 GB at half resolution). A labelled
    pixel learns from the quarter-grid cell it lies in.
    """
    complete = completeness(labels, params, model.resolution_m)
    prob, feats = predict(model, rgb, features=True, progress=progress,
                          context=complete >= params.context_from)
    assert feats is not None  # asked for
    logit = logit_of(prob)
    q_rows, q_cols = feats.shape[1:]
    if len(feats) > model.decoder_channels:
        feats = np.concatenate([feats[:model.decoder_channels], principal_components(
            feats[model.decoder_channels:], params.context_components)])
    x = correction_features(quarter(logit), feats, quarter(np.moveaxis(rgb, -1, 0)),
                            tuple(s / 4 for s in params.context_px), params.smooth_px / 4)
    del feats
    # Pixels as rows: the few thousand the fits read are gathered once into (n, C) arrays.
    flat_x, flat_logit = x.reshape(x.shape[0], -1).T, logit.ravel()
    rows, cols = logit.shape
    odd = ((np.arange(rows)[:, None] // params.block_px
            + np.arange(cols)[None, :] // params.block_px) % 2).astype(bool).ravel()

    def cell(index: np.ndarray) -> np.ndarray:
        """The quarter-grid cells (flat) of full-grid pixels (flat): only the sampled
        pixels' are ever needed, so no whole-image index array is made."""
        return (index // cols // 4) * q_cols + (index % cols) // 4

    learn = training_pixels(labels, prob, params, complete, within=~odd, seed=1)
    held, target, weight = training_pixels(labels, prob, params, complete, within=odd,
                                           seed=2)
    trial = fit_correction(flat_x[cell(learn[0])], flat_logit[learn[0]], learn[1], learn[2],
                           params)
    said = labels.ravel()[held] != 0  # the cut is judged by the labels, not the anchors
    held, road, weight = held[said], target[said] > 0.5, weight[said]
    judged = 1 / (1 + np.exp(-(flat_logit[held] + trial(flat_x[cell(held)]))))
    threshold = best_threshold(judged, road, weight, model.threshold)
    held_adapted = agreement(judged, road, weight, threshold)
    held_network = agreement(prob.ravel()[held], road, weight, model.threshold)
    if held_adapted <= held_network + params.gate_margin:
        return Adapted(np.where(labels == NOT_ROAD, 0.0, prob).astype(np.float32), prob,
                       model.threshold, False, held_network, held_adapted, params.gate_margin)
    index, target, weight = training_pixels(labels, prob, params, complete)
    correction = fit_correction(flat_x[cell(index)], flat_logit[index], target, weight, params)
    field = correction.of_channels(x.reshape(x.shape[0], -1)).astype(np.float32).reshape(
        q_rows, q_cols)
    z = logit + cv2.resize(field, (4 * q_cols, 4 * q_rows),
                           interpolation=cv2.INTER_LINEAR)[:rows, :cols]
    adapted = (1 / (1 + np.exp(-z))).astype(np.float32)
    # Where a person said "not road" it is not: a deleted false road never comes back where it
    # was, whatever the correction learnt from it for the rest of the image.
    adapted[labels == NOT_ROAD] = 0.0
    return Adapted(adapted, prob, threshold, True, held_network, held_adapted, params.gate_margin)
