"""``ugvmap roads train``: train the road model from labelled scenes and export it to ONNX.

Reproducible by construction: one seed drives the crop sampler, the weight initialisation and
the data order; PyTorch runs single-process on the CPU with a fixed thread count. Each epoch
prints the loss and the model-selection scores on the hold-out scenes
(:func:`ingest.roads.model.data.is_holdout`); the checkpoint with the best hold-out F1 is
exported, with the probability threshold that maximised it.

Loss: BCE + soft Dice, both masked by the label weight. BCE alone under-calls roads (about
one pixel in ten is road); Dice alone is unstable early. Their sum is the usual remedy.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from tqdm import tqdm

from ingest.roads import RoadsInputError
from ingest.roads.model.data import (
    CropSampler,
    Scene,
    is_holdout,
    load_scene,
    training_pairs,
)
from ingest.roads.model.net import WIDTHS, RoadUNet

THRESHOLDS = tuple(np.round(np.arange(0.2, 0.81, 0.05), 2))


@dataclass
class TrainConfig:
    """Every choice a training run makes; stored beside the weights."""

    resolution_m: float = 1.0
    crop_px: int = 224
    batch: int = 8
    epochs: int = 32
    steps_per_epoch: int = 80
    lr: float = 2e-3
    weight_decay: float = 1e-4
    seed: int = 0
    threads: int = 2
    hue_jitter: float = 0.0
    """Colour-wheel fraction of random hue rotation (arid and green scenes look alike)."""
    grey_p: float = 0.05
    """Share of crops turned grey (single-band imagery)."""
    widths: tuple[int, ...] = WIDTHS
    max_scenes: int | None = None
    """Use only the first N training scenes (CI-sized runs)."""
    exclude: list[str] = field(default_factory=list)
    """sha16 of images never to train on (the validation set)."""


def masked_loss(logit: torch.Tensor, road: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """BCE + (1 - soft Dice), counting only pixels with weight 1."""
    bce = F.binary_cross_entropy_with_logits(logit, road, weight=weight, reduction="sum")
    bce = bce / weight.sum().clamp(min=1)
    prob = torch.sigmoid(logit) * weight
    inter = (prob * road).sum()
    dice = (2 * inter + 1) / (prob.sum() + (road * weight).sum() + 1)
    return bce + 1 - dice


def predict_scene(model: RoadUNet, rgb: np.ndarray) -> np.ndarray:
    """Road probability of a whole (small) scene, padded to the network's 16 px grid."""
    rows, cols = rgb.shape[:2]
    pr, pc = -rows % 16, -cols % 16
    x = np.pad(rgb.astype(np.float32) / 255, ((0, pr), (0, pc), (0, 0)), mode="reflect")
    with torch.no_grad():
        logit, _ = model(torch.from_numpy(x.transpose(2, 0, 1).copy())[None])
    return torch.sigmoid(logit)[0, 0, :rows, :cols].numpy()


def holdout_scores(model: RoadUNet, scenes: list[Scene]) -> dict:
    """Pixel F1 per threshold over all hold-out scenes, and the best threshold."""
    model.eval()
    tp = np.zeros(len(THRESHOLDS))
    fp = np.zeros(len(THRESHOLDS))
    fn = np.zeros(len(THRESHOLDS))
    for scene in scenes:
        prob = predict_scene(model, scene.rgb)
        known = scene.weight.astype(bool)
        road = scene.road.astype(bool)[known]
        p = prob[known]
        for i, t in enumerate(THRESHOLDS):
            pred = p >= t
            tp[i] += np.sum(pred & road)
            fp[i] += np.sum(pred & ~road)
            fn[i] += np.sum(~pred & road)
    f1 = 2 * tp / np.maximum(2 * tp + fp + fn, 1)
    best = int(np.argmax(f1))
    return {"f1": float(f1[best]), "threshold": float(THRESHOLDS[best]),
            "precision": float(tp[best] / max(tp[best] + fp[best], 1)),
            "recall": float(tp[best] / max(tp[best] + fn[best], 1)),
            "f1_at_0.5": float(f1[THRESHOLDS.index(0.5)])}


def _batch(sampler: CropSampler, n: int) -> tuple[torch.Tensor, ...]:
    crops = [sampler.crop() for _ in range(n)]
    return tuple(torch.from_numpy(np.stack(parts)) for parts in zip(*crops, strict=True))


def train(data: Path, out: Path, config: TrainConfig, progress: bool = True) -> dict:
    """Train, select, export; returns the run's report (also written to ``out``)."""
    from ingest.roads.model.export import export_onnx, write_model_card

    torch.manual_seed(config.seed)
    torch.set_num_threads(config.threads)
    pairs = training_pairs(data, config.exclude)
    train_pairs = [p for p in pairs if not is_holdout(p)][:config.max_scenes]
    hold_pairs = [p for p in pairs if is_holdout(p)][:config.max_scenes]
    if not train_pairs or not hold_pairs:
        raise RoadsInputError(f"{data}: need training and hold-out scenes, found "
                              f"{len(train_pairs)} and {len(hold_pairs)}")
    load = tqdm(train_pairs + hold_pairs, desc="load scenes", unit="scene", disable=not progress)
    scenes = [load_scene(data, p, config.resolution_m) for p in load]
    train_scenes, hold_scenes = scenes[:len(train_pairs)], scenes[len(train_pairs):]
    sampler = CropSampler(train_scenes, config.crop_px, config.seed, config.hue_jitter,
                          config.grey_p)
    model = RoadUNet(config.widths)
    opt = torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    total = config.epochs * config.steps_per_epoch
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=config.lr, total_steps=total,
                                                pct_start=0.1)
    history, best, best_state = [], None, None
    started = time.perf_counter()
    for epoch in range(1, config.epochs + 1):
        model.train()
        losses = []
        bar = tqdm(range(config.steps_per_epoch), desc=f"epoch {epoch}/{config.epochs}",
                   unit="batch", disable=not progress, leave=False)
        for _ in bar:
            rgb, road, weight = _batch(sampler, config.batch)
            logit, _ = model(rgb)
            loss = masked_loss(logit, road, weight)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            losses.append(loss.item())
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.3f}")
        scores = holdout_scores(model, hold_scenes)
        row = {"epoch": epoch, "loss": float(np.mean(losses)),
               "minutes": (time.perf_counter() - started) / 60, **scores}
        history.append(row)
        tqdm.write(f"epoch {epoch:3d}  loss {row['loss']:.4f}  hold-out F1 {scores['f1']:.3f} "
                   f"(P {scores['precision']:.3f} R {scores['recall']:.3f} @ "
                   f"{scores['threshold']:.2f})  {row['minutes']:.1f} min")
        if best is None or scores["f1"] > best["f1"]:
            best = row
            best_state = {k: v.clone() for k, v in model.state_dict().items()}
    assert best is not None and best_state is not None  # epochs >= 1
    model.load_state_dict(best_state)
    model.eval()
    out.mkdir(parents=True, exist_ok=True)
    torch.save(model.state_dict(), out / "weights.pt")
    report = {
        "config": asdict(config), "best_epoch": best["epoch"], "threshold": best["threshold"],
        "holdout": {k: best[k] for k in ("f1", "precision", "recall", "f1_at_0.5")},
        "history": history, "train_minutes": history[-1]["minutes"],
        "train_scenes": [s.name for s in train_scenes],
        "holdout_scenes": [s.name for s in hold_scenes],
        "parameters": sum(p.numel() for p in model.parameters()),
        "torch": torch.__version__,
    }
    export_onnx(model, out / "model.onnx", config.resolution_m, best["threshold"])
    (out / "training.json").write_text(json.dumps(report, indent=1))
    write_model_card(out, report)
    return report


def initial_loss(config: TrainConfig, data: Path) -> float:
    """Loss of an untrained model on one batch (tests compare training against it)."""
    torch.manual_seed(config.seed)
    pairs = [p for p in training_pairs(data, config.exclude) if not is_holdout(p)]
    scenes = [load_scene(data, p, config.resolution_m) for p in pairs[:config.max_scenes]]
    rgb, road, weight = _batch(CropSampler(scenes, config.crop_px, config.seed), config.batch)
    with torch.no_grad():
        return float(masked_loss(RoadUNet(config.widths)(rgb)[0], road, weight))

