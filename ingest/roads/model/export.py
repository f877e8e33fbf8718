"""ONNX export of the trained network and its model card.

The ONNX file carries everything inference needs in its metadata (ground resolution,
probability threshold, output names), so ``models/roads-v1/model.onnx`` alone is a usable
model and onnxruntime never needs torch. The graph outputs the road *probability* (sigmoid
applied inside) and the last decoder feature map (for per-job adaptation).
"""

from __future__ import annotations

import json
from pathlib import Path

import onnx
import torch
from torch import nn

from ingest.roads.model.net import RoadUNet

OPSET = 17


class _Exported(nn.Module):
    def __init__(self, net: RoadUNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, rgb: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        logit, features = self.net(rgb)
        return torch.sigmoid(logit), features


def export_onnx(model: RoadUNet, path: Path, resolution_m: float, threshold: float) -> None:
    """Write ``path`` with dynamic batch/height/width and the model's metadata."""
    model.eval()
    example = torch.rand(1, 3, 64, 64)
    tmp = path.with_suffix(".tmp.onnx")
    torch.onnx.export(_Exported(model), (example,), str(tmp), input_names=["rgb"],
                      output_names=["road", "features"], opset_version=OPSET, dynamo=False,
                      dynamic_axes={"rgb": {0: "n", 2: "h", 3: "w"},
                                    "road": {0: "n", 2: "h", 3: "w"},
                                    "features": {0: "n", 2: "h", 3: "w"}})
    proto = onnx.load(str(tmp))
    meta = {"resolution_m": resolution_m, "threshold": threshold, "grid_px": 16,
            "input": "RGB float32 (N, 3, H, W) in [0, 1], normalised per image",
            "outputs": "road probability (N, 1, H, W); decoder features (N, C, H, W)"}
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, json.dumps(value)
    onnx.save(proto, str(path))
    tmp.unlink()


def write_model_card(out: Path, report: dict) -> None:
    """``README.md`` beside the weights: data, resolution, architecture, time, scores.

    The validation table on ``shared/data/road_imagery`` is filled in by
    ``bench/roads_accuracy.py --card`` (it needs the extraction pipeline, not just pixels).
    """
    cfg = report["config"]
    hue, grey = cfg.get("hue_jitter", 0.0), cfg.get("grey_p", 0.05)
    rows = "\n".join(
        f"| {h['epoch']} | {h['loss']:.4f} | {h['f1']:.3f} | {h['precision']:.3f} | "
        f"{h['recall']:.3f} | {h['threshold']:.2f} | {h['minutes']:.1f} |"
        for h in report["history"])
    card = f"""# roads-v1 — road segmentation model shipped with ugvmap

**Licence status: research use only.** The training images and labels come from public
repositories that state no data licence (Massachusetts Roads, EPFL road segmentation) or a
code licence only (SpaceNet via CosmiQ/apls, Apache-2.0 for the code, CC BY-SA 4.0 upstream
for the imagery); see `../../../shared/data/road_training/SOURCES.md`. Until those licences are
checked, do not ship this model in a product.

## What it is
- Task: per-pixel road probability from RGB aerial / satellite / mosaic imagery.
- Ground resolution: **{cfg['resolution_m']} m/px**. Every input is resampled to it from its
  own m/px (`ugvmap extract-roads` does this), contrast-stretched between its 0.5th and 99.5th
  percentiles (any dtype, 1 or 3+ bands).
- Architecture: U-Net, widths {list(cfg['widths'])}, 4 down-samplings (16 px grid), 3x3 conv
  + BatchNorm + ReLU; {report['parameters']:,} parameters. Outputs the probability (sigmoid in
  the graph) and the last decoder feature map (used by per-job adaptation).
- Runtime: `model.onnx` (opset {OPSET}) on onnxruntime, tiled with overlap and blending; torch
  is only needed to train (`pip install -e .[train]`).

## Training
Reproduce (same seed, same machine kind: same weights up to floating-point thread order):
```sh
pip install -e '.[train]'
ugvmap roads train --data ../shared/data/road_training \\
    --exclude-images ../shared/data/road_imagery \\
    --out models/roads-v1 --epochs {cfg['epochs']} --steps-per-epoch {cfg['steps_per_epoch']} \\
    --seed {cfg['seed']} --hue-jitter {hue} --grey-p {grey}
```
- Data: `shared/data/road_training/pairs.json` minus every image byte-identical to one in
  `shared/data/road_imagery` (the validation set), split into {len(report['train_scenes'])}
  training scenes and {len(report['holdout_scenes'])} hold-out scenes (model selection only:
  `mass_14` and every 12th EPFL tile).
- Labels: masks >= 128 = road; SpaceNet centerlines rasterised (road within 2 m, unlabelled
  2–6 m); Massachusetts white no-data and unlabelled margins excluded from the loss.
- Crops {cfg['crop_px']} px, batch {cfg['batch']}, {cfg['epochs']} epochs x
  {cfg['steps_per_epoch']} steps, AdamW lr {cfg['lr']} one-cycle, seed {cfg['seed']},
  {cfg['threads']} CPU threads; augmentation: scale 0.7–1.4, 90° rotations, flips, saturation,
  per-channel gain, contrast, brightness, gamma, blur, noise, greyscale
  (p = {grey}), hue rotation (±{hue} of the wheel).
- Loss: BCE + soft Dice (masked). Checkpoint and threshold chosen by hold-out pixel F1:
  epoch {report['best_epoch']}, threshold {report['threshold']:.2f}, hold-out F1
  {report['holdout']['f1']:.3f} (P {report['holdout']['precision']:.3f},
  R {report['holdout']['recall']:.3f}).
- Time on this machine (2 CPU cores): {report['train_minutes']:.1f} min, torch {report['torch']}.

## Per-epoch hold-out report
| epoch | loss | F1 | precision | recall | threshold | minutes |
|---|---|---|---|---|---|---|
{rows}

## Validation on shared/data/road_imagery
Measured with `bench/roads_accuracy.py --card` (none of these images was trained on). Each
image's quadrant with the most road is the job's sample for the adapted / learned / spectral
rows; every row is scored on the other three quadrants: buffer precision (P) and recall (R)
of centerlines at 1 m and 2 m, and APLS connectivity (5 m node snap).

VALIDATION_TABLE
"""
    (out / "README.md").write_text(card)
