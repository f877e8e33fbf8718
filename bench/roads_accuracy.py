"""Road-extraction accuracy on the shared labelled imagery, every classifier, one table.

    .venv/bin/python bench/roads_accuracy.py [--only massachusetts_01 ...]
        [--classifiers model adapted learned spectral] [--models A.onnx B.onnx ...]
        [--card models/roads-v2/README.md]

Every road model given (default: the shipped roads-v1 and roads-v2) runs in the same run on
the same images, zero-shot and adapted, so their rows compare directly; the ablation models of
``models/roads-v2/card_notes.md`` were scored this way (``--classifiers model --models ...``).

Protocol (:mod:`testkit.roads_accuracy`): the quadrant with the most labelled road is the
job's sample (adapted, learned and spectral train on it; the zero-shot model gets nothing);
every classifier is scored on the other three quadrants with buffer precision/recall at 1 m
and 2 m and APLS connectivity. None of these images is in the model's training data
(``ugvmap roads train --exclude-images`` drops byte-identical files). The baselines are the
previous default (``learned``) and the survey's spectral line, run on the same images in
the same run. ``--card`` writes the table into the model card's validation section.

``--ablation`` instead measures each clean-up step after skeletonisation on the zero-shot
model: none, + spur pruning, + gap bridging, + short-fragment removal (the default).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from dataclasses import replace  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from ingest.roads.model.data import normalise  # noqa: E402
from ingest.roads.pipeline import ExtractParams, extract_roads  # noqa: E402
from ingest.roads.topology import TopologyParams  # noqa: E402
from testkit.roads_accuracy import (  # noqa: E402
    SAMPLES,
    evaluate_sample,
    holdout_samples,
    load_sample,
)

DATA = REPO.parent / "shared" / "data" / "road_imagery"
TRAINING = REPO.parent / "shared" / "data" / "road_training"
CLASSIFIERS = ("model", "adapted", "learned", "spectral")
DEFAULT_MODELS = [p for p in (REPO / "models" / f"roads-v{v}" / "model.onnx" for v in (1, 2))
                  if p.is_file()]
LABELS = {"model": "zero-shot model", "adapted": "adapted model",
          "learned": "learned (old default)", "spectral": "spectral line"}


def ablation_params() -> dict[str, ExtractParams]:
    """The zero-shot pipeline with its clean-up steps switched on one at a time."""
    full = ExtractParams()
    off = TopologyParams(bridge_max_m=0.0, min_fragment_m=0.0)
    return {
        "no clean-up": replace(full, spur_max_m=0.0, topology=off),
        "+ spur pruning": replace(full, topology=off),
        "+ gap bridging": replace(full, topology=replace(full.topology, min_fragment_m=0.0)),
        "+ drop fragments": full,
    }


def run_ablation(samples: list, data: Path) -> None:
    """Print P/R at 2 m and APLS per clean-up stage, per image and mean."""
    variants = ablation_params()
    print(f"| {'sample':18} | {'clean-up':18} | P@2m  | R@2m  | APLS  |")
    print("|" + "---|" * 5)
    sums: dict[str, list[tuple[float, float, float]]] = {}
    for sample in samples:
        for name, params in variants.items():
            ev = evaluate_sample(sample, data, "model", params=params)
            two = ev.scores[1]
            sums.setdefault(name, []).append((two.precision, two.recall, ev.apls))
            print(f"| {sample.name:18} | {name:18} | {two.precision:.3f} | {two.recall:.3f} | "
                  f"{ev.apls:.3f} |", flush=True)
    for name, rows in sums.items():
        p, r, a = (sum(x[i] for x in rows) / len(rows) for i in range(3))
        print(f"| **mean** | {name:18} | {p:.3f} | {r:.3f} | {a:.3f} |")


def picture(sample, data: Path, params: ExtractParams, out: Path, width: int = 640) -> None:
    """``out``: the image with the truth (green) and the zero-shot extraction (red) drawn."""
    image, truth = load_sample(sample, data)
    result = extract_roads(image, None, replace(params, classifier="model"))
    rgb = np.round(normalise(image.pixels, image.valid) * 255).astype(np.uint8)[..., ::-1]
    scale = width / rgb.shape[1]
    canvas = cv2.resize(rgb, (width, round(rgb.shape[0] * scale)), interpolation=cv2.INTER_AREA)
    for lines, colour in ((truth.lines, (60, 220, 60)), (result.source_lines(), (40, 40, 255))):
        for line in lines:
            pts = np.round(np.asarray(line) * scale).astype(np.int32)
            cv2.polylines(canvas, [pts], False, colour, 2, cv2.LINE_AA)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), canvas, [cv2.IMWRITE_JPEG_QUALITY, 80])


def model_runs(classifiers: list[str], models: list[Path]
               ) -> list[tuple[str, str, ExtractParams]]:
    """(row label, classifier, params) for every classifier, once per model for the model ones."""
    runs = []
    for classifier in classifiers:
        if classifier in ("model", "adapted"):
            runs += [(f"{LABELS[classifier]} ({m.parent.name})", classifier,
                      ExtractParams(model_path=m)) for m in models]
        else:
            runs.append((LABELS[classifier], classifier, ExtractParams()))
    return runs


def main() -> None:
    """Score every classifier on the validation imagery and print (or write into the model card) the
    table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", help="sample names to run")
    parser.add_argument("--classifiers", nargs="*", default=list(CLASSIFIERS),
                        choices=CLASSIFIERS)
    parser.add_argument("--models", nargs="*", type=Path, default=DEFAULT_MODELS,
                        help="ONNX road models to compare (default: roads-v1 and roads-v2)")
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--card", type=Path, help="model card to write the table into")
    parser.add_argument("--ablation", action="store_true",
                        help="measure each topology clean-up step (zero-shot model)")
    parser.add_argument("--holdout", action="store_true",
                        help="score the training set's hold-out scenes instead (where pipeline "
                             "settings are chosen)")
    parser.add_argument("--set", dest="settings", nargs="*", default=[], metavar="NAME=VALUE",
                        help="pipeline settings (ExtractParams fields, numbers) for every run")
    parser.add_argument("--pictures", type=Path, metavar="DIR",
                        help="instead of scoring, draw truth and zero-shot extraction per "
                             "sample and model into DIR/<sample>-<model>.jpg")
    args = parser.parse_args()
    if args.holdout:
        args.data = TRAINING
    pool = holdout_samples(TRAINING) if args.holdout else SAMPLES
    samples = [s for s in pool if not args.only or s.name in args.only]
    defaults = ExtractParams()
    # Each value takes its field's type (tta is a count, the thresholds are fractions).
    settings = {k: type(getattr(defaults, k))(v)
                for k, v in (item.split("=", 1) for item in args.settings)}
    if args.pictures:
        for sample in samples:
            for model in args.models:
                out = args.pictures / f"{sample.name}-{model.parent.name}.jpg"
                picture(sample, args.data, ExtractParams(model_path=model, **settings), out)
                print(out, flush=True)
        return
    if args.ablation:
        run_ablation(samples, args.data)
        return
    runs = [(label, classifier, replace(params, **settings))
            for label, classifier, params in model_runs(args.classifiers, args.models)]
    width = max(22, *(len(label) for label, _, _ in runs))
    head = (f"| {'sample':18} | {'classifier':{width}} | P@1m  | R@1m  | P@2m  | R@2m  | "
            f"APLS  | seconds |")
    lines = [head, "|" + "---|" * 8]
    print(head, flush=True)
    totals: dict[str, list[tuple[float, float, float]]] = {}
    for sample in samples:
        for label, classifier, params in runs:
            ev = evaluate_sample(sample, args.data, classifier, params=params)
            one, two = ev.scores
            row = (f"| {sample.name:18} | {label:{width}} | {one.precision:.3f} | "
                   f"{one.recall:.3f} | {two.precision:.3f} | {two.recall:.3f} | "
                   f"{ev.apls:.3f} | {ev.seconds:7.1f} |")
            lines.append(row)
            print(row, flush=True)
            totals.setdefault(label, []).append((two.precision, two.recall, ev.apls))
    means = {label: [sum(x[i] for x in rows) / len(rows) for i in range(3)]
             for label, rows in totals.items()}
    for label, (p, r, a) in means.items():
        row = (f"| **mean** ({len(totals[label])} images) | {label:{width}} | | | "
               f"**{p:.3f}** | **{r:.3f}** | **{a:.3f}** | |")
        lines.append(row)
        print(row)
    baseline = next(iter(means))  # the first model's zero-shot row (roads-v1 by default)
    for label, (p, r, a) in means.items():
        bp, br, ba = means[baseline]
        print(f"{label} / {baseline}: precision @2m {p / max(bp, 1e-9):.2f}x, recall "
              f"{r / max(br, 1e-9):.2f}x, APLS {a / max(ba, 1e-9):.2f}x")
    for label, rows in totals.items():
        print(f"{label}: lowest precision @2m {min(x[0] for x in rows):.3f}, "
              f"lowest recall @2m {min(x[1] for x in rows):.3f}")
    if args.card:
        text = args.card.read_text()
        table = "\n".join(lines)
        marker = "VALIDATION_TABLE"
        if marker not in text:
            sys.exit(f"{args.card} has no {marker} placeholder (already filled?)")
        args.card.write_text(text.replace(marker, table))
        print(f"table written into {args.card}")


if __name__ == "__main__":
    main()
