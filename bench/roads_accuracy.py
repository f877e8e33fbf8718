"""Road-extraction accuracy on the shared labelled imagery, every classifier, one table.

    .venv/bin/python bench/roads_accuracy.py [--only massachusetts_01 ...]
        [--classifiers model adapted learned spectral] [--card models/roads-v1/README.md]

Protocol (:mod:`ingest.roads.accuracy`): the quadrant with the most labelled road is the
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

from ingest.roads.accuracy import SAMPLES, evaluate_sample  # noqa: E402
from ingest.roads.pipeline import ExtractParams  # noqa: E402
from ingest.roads.topology import TopologyParams  # noqa: E402

DATA = REPO.parent / "shared" / "data" / "road_imagery"
CLASSIFIERS = ("model", "adapted", "learned", "spectral")
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


def main() -> None:
    """Score every classifier on the validation imagery and print (or write into the model card) the
    table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", help="sample names to run")
    parser.add_argument("--classifiers", nargs="*", default=list(CLASSIFIERS),
                        choices=CLASSIFIERS)
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--card", type=Path, help="model card to write the table into")
    parser.add_argument("--ablation", action="store_true",
                        help="measure each topology clean-up step (zero-shot model)")
    args = parser.parse_args()
    samples = [s for s in SAMPLES if not args.only or s.name in args.only]
    if args.ablation:
        run_ablation(samples, args.data)
        return
    head = (f"| {'sample':18} | {'classifier':22} | P@1m  | R@1m  | P@2m  | R@2m  | "
            f"APLS  | seconds |")
    lines = [head, "|" + "---|" * 8]
    print(head, flush=True)
    totals: dict[str, list[tuple[float, float, float]]] = {}
    for sample in samples:
        for classifier in args.classifiers:
            ev = evaluate_sample(sample, args.data, classifier)
            one, two = ev.scores
            row = (f"| {sample.name:18} | {LABELS[classifier]:22} | {one.precision:.3f} | "
                   f"{one.recall:.3f} | {two.precision:.3f} | {two.recall:.3f} | "
                   f"{ev.apls:.3f} | {ev.seconds:7.1f} |")
            lines.append(row)
            print(row, flush=True)
            totals.setdefault(classifier, []).append((two.precision, two.recall, ev.apls))
    means = {}
    for classifier, rows in totals.items():
        p, r, a = (sum(x[i] for x in rows) / len(rows) for i in range(3))
        means[classifier] = (p, r, a)
        row = (f"| **mean** ({len(rows)} images) | {LABELS[classifier]:22} | | | "
               f"**{p:.3f}** | **{r:.3f}** | **{a:.3f}** | |")
        lines.append(row)
        print(row)
    for base in ("learned", "spectral"):
        if "model" in means and base in means:
            print(f"zero-shot / {base} precision @2m: "
                  f"{means['model'][0] / max(means[base][0], 1e-9):.2f}x, recall "
                  f"{means['model'][1] / max(means[base][1], 1e-9):.2f}x")
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
