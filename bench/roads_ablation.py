"""Road model ablation: what each ingredient of roads-v2 is worth, in one protocol.

    .venv/bin/python bench/roads_ablation.py [--epochs 3] [--steps 100] [--threads 1]
        [--only pretrained scratch ...] [--out bench/out/ablation]

Trains short runs that differ in one thing each from the same seed and the same number of
steps, then scores every one zero-shot on ``../shared/data/road_imagery`` (the validation
images, kept out of every run with ``--exclude-images``) with the protocol of
``bench/roads_accuracy.py`` (P/R at 2 m and APLS on the three quadrants without the most road):

- ``pretrained``: EfficientNet-Lite0 with ImageNet weights at 0.5 m/px, all 259 pairs
  (the roads-v2 recipe, shortened) — the baseline of the table;
- ``scratch``: the same network from random weights;
- ``1m``: pretrained, at 1 m/px (roads-v1's grid);
- ``old-data``: pretrained, without what the issue added (the ETH CIL-2022 tiles and the
  three Massachusetts edge tiles; 112 pairs as before);
- ``procedural``: pretrained + procedural scenes (``--augment procedural_p=0.25``).

Short runs rank recipes, they do not reach the shipped model's figures (which the model card
reports from its own, longer run). A run already in ``--out`` is scored, not trained again.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ingest.roads.model.data import Augment, image_hashes  # noqa: E402
from ingest.roads.model.train import TrainConfig, train  # noqa: E402
from ingest.roads.pipeline import ExtractParams  # noqa: E402
from testkit.roads_accuracy import SAMPLES, evaluate_sample  # noqa: E402

DATA = REPO.parent / "shared" / "data" / "road_training"
VALIDATION = REPO.parent / "shared" / "data" / "road_imagery"
RECIPE = Augment(scale_max=2.0, hue=0.5, grey_p=0.15, shuffle_p=0.2, invert_p=0.1)
"""roads-v2's augmentation (its model card's command line)."""
ADDED_BY_ISSUE = ("ClementSicard/unet-swin", "parth1620/Road_seg_dataset")
"""Repositories of the pairs issue 19 added (CIL-2022; three Massachusetts edge tiles)."""


def variants(base: TrainConfig) -> dict[str, tuple[TrainConfig, Path]]:
    """name -> (config, training data folder)."""
    return {
        "pretrained": (base, DATA),
        "scratch": (replace(base, pretrained=False), DATA),
        "1m": (replace(base, resolution_m=1.0, crop_px=base.crop_px // 2), DATA),
        "old-data": (base, old_data()),
        "procedural": (replace(base, augment=replace(base.augment, procedural_p=0.25)), DATA),
    }


def old_data() -> Path:
    """A folder with the training set as it was before the issue added data: symlinks to the
    shared files and a filtered ``pairs.json`` (made once under ``bench/out``)."""
    folder = REPO / "bench" / "out" / "road_training_old"
    pairs = json.loads((DATA / "pairs.json").read_text())
    kept = [p for p in pairs if p.get("repository") not in ADDED_BY_ISSUE]
    folder.mkdir(parents=True, exist_ok=True)
    for entry in DATA.iterdir():
        link = folder / entry.name
        if entry.is_dir() and not link.exists():
            os.symlink(entry, link)
    (folder / "pairs.json").write_text(json.dumps(kept))
    return folder


def main() -> None:
    """Train what is missing, score everything, print one table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--only", nargs="*")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "out" / "ablation")
    args = parser.parse_args()
    base = TrainConfig(epochs=args.epochs, steps_per_epoch=args.steps, threads=args.threads,
                       augment=RECIPE, exclude=sorted(image_hashes(VALIDATION)))
    rows = []
    for name, (config, data) in variants(base).items():
        if args.only and name not in args.only:
            continue
        out = args.out / name
        report_path = out / "training.json"
        if not report_path.is_file():
            print(f"training {name} ...", flush=True)
            train(data, out, config, progress=True)
        report = json.loads(report_path.read_text())
        params = ExtractParams(model_path=out / "model.onnx")
        scores = []
        start = time.perf_counter()
        for sample in SAMPLES:
            ev = evaluate_sample(sample, VALIDATION, "model", params=params)
            scores.append((ev.scores[1].precision, ev.scores[1].recall, ev.apls))
        mean = [sum(s[i] for s in scores) / len(scores) for i in range(3)]
        rows.append((name, len(report["train_scenes"]), report["holdout"]["f1"],
                     report["train_minutes"], *mean, min(s[0] for s in scores),
                     min(s[1] for s in scores), time.perf_counter() - start))
        print(f"scored {name}", flush=True)
    print("| variant | training scenes | hold-out F1 | training min | P@2m | R@2m | APLS "
          "| lowest P | lowest R |")
    print("|" + "---|" * 9)
    for name, n, f1, minutes, p, r, a, low_p, low_r, _ in rows:
        print(f"| {name} | {n} | {f1:.3f} | {minutes:.1f} | {p:.3f} | {r:.3f} | {a:.3f} | "
              f"{low_p:.3f} | {low_r:.3f} |")


if __name__ == "__main__":
    main()
