"""``ugvmap roads train``: train the road model and export it to ONNX.

Reproducible by construction: one seed drives the crop sampler, the weight initialisation and
the data order; PyTorch runs single-process on the CPU with a fixed thread count. Each epoch
prints the loss and the model-selection scores on the hold-out scenes
(:func:`ingest.roads.model.data.is_holdout`); the checkpoint with the best hold-out F1 is
exported, with the probability threshold that maximised it.

Long runs (hours on two cores) survive being cut off: after every epoch the whole state
(weights, optimiser, schedule, sampler and torch random state, history, best weights) goes to
``checkpoint.pt`` in the output folder, and ``--resume`` carries on from it with the same
result as an uncut run. Whenever the hold-out improves, the model folder is rewritten (ONNX,
report, card), so it always holds a usable model.

Loss: BCE + soft Dice, both masked by the label weight. BCE alone under-calls roads (about
one pixel in ten is road); Dice alone is unstable early. Their sum is the usual remedy. The
pretrained encoder learns at a fraction of the decoder's rate, so the first, noisy steps of a
random decoder do not wash out what ImageNet taught it.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from torch import nn
from tqdm import tqdm

from ingest.roads import RoadsInputError
from ingest.roads.model.data import (
    Augment,
    CropSampler,
    Scene,
    is_holdout,
    load_scene,
    training_pairs,
)
from ingest.roads.model.net import WIDTHS, Arch, LiteUNet, build

THRESHOLDS = tuple(np.round(np.arange(0.2, 0.81, 0.05), 2))


def native_bf16(cpuinfo: Path = Path("/proc/cpuinfo")) -> bool:
    """Whether this CPU computes bfloat16 natively (AVX-512 BF16 or AMX): on one without
    (an AMD EPYC with AVX2 only), bf16 autocast is emulated and the first batch of the
    roads-v2 recipe took 225 s instead of a few."""
    try:
        flags = set(cpuinfo.read_text(encoding="utf-8", errors="replace").split())
    except OSError:
        return False
    return bool(flags & {"avx512_bf16", "amx_bf16"})


@dataclass
class TrainConfig:
    """Every choice a training run makes; stored beside the weights."""

    arch: Arch = "lite0"
    pretrained: bool = True
    """``lite0``/``lite2``: start the encoder from ImageNet weights (False = from scratch, the
    ablation)."""
    encoder_lr_scale: float = 0.3
    resolution_m: float = 0.5
    crop_px: int = 256
    batch: int = 8
    epochs: int = 30
    steps_per_epoch: int = 100
    lr: float = 2e-3
    weight_decay: float = 1e-4
    seed: int = 0
    threads: int = 2
    bf16: bool = field(default_factory=native_bf16)
    """Train under bfloat16 autocast: twice as fast on CPUs with AVX-512 BF16 (BatchNorm and
    the loss stay float32; hold-out scoring and the exported model are float32), and far
    slower where it is emulated, so by default only where the CPU does it natively
    (:func:`native_bf16`; a default of always made every CI-sized run of the test suite take
    ~47 s on an AVX2-only machine)."""
    augment: Augment = field(default_factory=Augment)
    widths: tuple[int, ...] = WIDTHS
    """``unet`` only: channels per level."""
    source_weight: dict[str, float] = field(default_factory=dict)
    """How much more often than its area says a scene of this source is drawn (``pairs.json``'s
    ``source``; :class:`~ingest.roads.model.data.CropSampler`)."""
    max_scenes: int | None = None
    """Use only the first N training scenes (CI-sized runs)."""
    exclude: list[str] = field(default_factory=list)
    """sha16 of images never to train on (the validation set)."""
    init: str | None = None
    """``weights.pt`` of an earlier run of the same architecture to start from (fine-tuning:
    a new recipe need not pay again for the epochs an earlier one already trained)."""
    init_sha16: str | None = None
    """sha16 of ``init``: the card names exactly which weights the run started from."""


def masked_loss(logit: torch.Tensor, road: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """BCE + (1 - soft Dice), counting only pixels with weight 1."""
    bce = F.binary_cross_entropy_with_logits(logit, road, weight=weight, reduction="sum")
    bce = bce / weight.sum().clamp(min=1)
    prob = torch.sigmoid(logit) * weight
    inter = (prob * road).sum()
    dice = (2 * inter + 1) / (prob.sum() + (road * weight).sum() + 1)
    return bce + 1 - dice


def predict_scene(model: nn.Module, rgb: np.ndarray) -> np.ndarray:
    """Road probability of a whole (small) scene, padded to the network's 16 px grid."""
    rows, cols = rgb.shape[:2]
    pr, pc = -rows % 16, -cols % 16
    x = np.pad(rgb.astype(np.float32) / 255, ((0, pr), (0, pc), (0, 0)), mode="reflect")
    with torch.no_grad():
        logit, _ = model(torch.from_numpy(x.transpose(2, 0, 1).copy())[None])
    return torch.sigmoid(logit)[0, 0, :rows, :cols].numpy()


def holdout_scores(model: nn.Module, scenes: list[Scene]) -> dict:
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


def _network(config: TrainConfig) -> nn.Module:
    return build(config.arch, config.pretrained, tuple(config.widths))


def _optimiser(model: nn.Module, config: TrainConfig) -> torch.optim.Optimizer:
    """AdamW; a pretrained encoder at ``encoder_lr_scale`` of the decoder's rate."""
    if isinstance(model, LiteUNet) and config.pretrained:
        encoder = {id(p) for p in model.encoder_parameters()}
        decoder = [p for p in model.parameters() if id(p) not in encoder]
        groups: list[dict[str, Any]] = [
            {"params": decoder},
            {"params": model.encoder_parameters(), "lr": config.lr * config.encoder_lr_scale}]
        return torch.optim.AdamW(groups, lr=config.lr, weight_decay=config.weight_decay)
    return torch.optim.AdamW(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)


def _config_key(config: TrainConfig) -> dict:
    """What must match for a checkpoint to be resumed (threads may differ)."""
    return {k: v for k, v in json.loads(json.dumps(asdict(config))).items() if k != "threads"}


def _load_checkpoint(path: Path, config: TrainConfig) -> dict | None:
    if not path.is_file():
        return None
    state = torch.load(path, map_location="cpu", weights_only=False)
    if state["config"] != _config_key(config):
        raise RoadsInputError(f"{path} was written by a run with other settings: resume it "
                              "with the same options, or train into another --out folder")
    return state


def _load_init(model: nn.Module, path: Path) -> None:
    """Start from the weights of an earlier run (``TrainConfig.init``)."""
    try:
        model.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))
    except (OSError, RuntimeError) as exc:
        raise RoadsInputError(f"--init {path}: not weights of this architecture ({exc})"
                              ) from exc


def _publish(model: nn.Module, best_state: dict, out: Path, report: dict) -> None:
    """Write the best weights so far as the model folder: ONNX, weights, report, card."""
    from ingest.roads.model.export import export_onnx, write_model_card

    current = {k: v.clone() for k, v in model.state_dict().items()}
    model.load_state_dict(best_state)
    model.eval()
    torch.save(best_state, out / "weights.pt")
    export_onnx(model, out / "model.onnx", report["config"]["resolution_m"], report["threshold"])
    (out / "training.json").write_text(json.dumps(report, indent=1))
    write_model_card(out, report)
    model.load_state_dict(current)


def train(data: Path, out: Path, config: TrainConfig, progress: bool = True,
          resume: bool = False, time_limit_min: float | None = None) -> dict:
    """Train, select, export; returns the run's report (also written to ``out``).

    With ``resume``, a ``checkpoint.pt`` in ``out`` from the same settings is carried on from
    (a run that already finished returns its report at once). ``time_limit_min`` stops after
    the first epoch that ends past that many minutes of this call (resume later)."""
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
    sampler = CropSampler(train_scenes, config.crop_px, config.seed, config.augment,
                          config.resolution_m, config.source_weight)
    model = _network(config)
    if config.init is not None:
        _load_init(model, Path(config.init))
    opt = _optimiser(model, config)
    total = config.epochs * config.steps_per_epoch
    sched = torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=[g["lr"] for g in opt.param_groups], total_steps=total, pct_start=0.1)
    out.mkdir(parents=True, exist_ok=True)
    checkpoint = out / "checkpoint.pt"
    history: list[dict] = []
    best: dict | None = None
    best_state: dict | None = None
    first, minutes_before = 1, 0.0
    state = _load_checkpoint(checkpoint, config) if resume else None
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        sampler.rng.bit_generator.state = state["sampler_rng"]
        torch.set_rng_state(state["torch_rng"])
        history, best, best_state = state["history"], state["best"], state["best_state"]
        first, minutes_before = state["epoch"] + 1, history[-1]["minutes"]
        tqdm.write(f"resuming after epoch {state['epoch']} ({minutes_before:.1f} min)")
    report: dict = {}
    started = time.perf_counter()
    for epoch in range(first, config.epochs + 1):
        model.train()
        losses = []
        bar = tqdm(range(config.steps_per_epoch), desc=f"epoch {epoch}/{config.epochs}",
                   unit="batch", disable=not progress, leave=False)
        for _ in bar:
            rgb, road, weight = _batch(sampler, config.batch)
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=config.bf16):
                logit, _ = model(rgb)
            loss = masked_loss(logit.float(), road, weight)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            losses.append(loss.item())
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.3f}")
        scores = holdout_scores(model, hold_scenes)
        row = {"epoch": epoch, "loss": float(np.mean(losses)),
               "minutes": minutes_before + (time.perf_counter() - started) / 60, **scores}
        history.append(row)
        tqdm.write(f"epoch {epoch:3d}  loss {row['loss']:.4f}  hold-out F1 {scores['f1']:.3f} "
                   f"(P {scores['precision']:.3f} R {scores['recall']:.3f} @ "
                   f"{scores['threshold']:.2f})  {row['minutes']:.1f} min")
        improved = best is None or scores["f1"] > best["f1"]
        if improved:
            best = row
            best_state = {k: v.clone() for k, v in model.state_dict().items()}
        assert best is not None and best_state is not None
        report = _report(config, best, history, train_scenes, hold_scenes, model)
        if improved:
            _publish(model, best_state, out, report)
        torch.save({"config": _config_key(config), "epoch": epoch, "model": model.state_dict(),
                    "opt": opt.state_dict(), "sched": sched.state_dict(),
                    "sampler_rng": sampler.rng.bit_generator.state,
                    "torch_rng": torch.get_rng_state(), "history": history, "best": best,
                    "best_state": best_state}, checkpoint.with_suffix(".tmp"))
        checkpoint.with_suffix(".tmp").replace(checkpoint)
        if time_limit_min is not None and (time.perf_counter() - started) / 60 >= time_limit_min:
            tqdm.write(f"time limit reached after epoch {epoch}: carry on with --resume")
            break
    if not report:  # resumed a finished run
        assert best is not None
        report = _report(config, best, history, train_scenes, hold_scenes, model)
    return report


def _report(config: TrainConfig, best: dict, history: list[dict], train_scenes: list[Scene],
            hold_scenes: list[Scene], model: nn.Module) -> dict:
    return {
        "config": json.loads(json.dumps(asdict(config))), "best_epoch": best["epoch"],
        "threshold": best["threshold"],
        "holdout": {k: best[k] for k in ("f1", "precision", "recall", "f1_at_0.5")},
        "history": history, "train_minutes": history[-1]["minutes"],
        "train_scenes": [s.name for s in train_scenes],
        "holdout_scenes": [s.name for s in hold_scenes],
        "parameters": sum(p.numel() for p in model.parameters()),
        "torch": torch.__version__,
    }


def initial_loss(config: TrainConfig, data: Path) -> float:
    """Loss of an untrained model on one batch (tests compare training against it)."""
    torch.manual_seed(config.seed)
    pairs = [p for p in training_pairs(data, config.exclude) if not is_holdout(p)]
    scenes = [load_scene(data, p, config.resolution_m) for p in pairs[:config.max_scenes]]
    rgb, road, weight = _batch(CropSampler(scenes, config.crop_px, config.seed), config.batch)
    with torch.no_grad():
        return float(masked_loss(_network(config)(rgb)[0], road, weight))
