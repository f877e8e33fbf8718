"""Road-extraction accuracy on the shared labelled imagery, both classifiers.

    .venv/bin/python bench/roads_accuracy.py [--only massachusetts_01 ...]

Protocol (:mod:`ingest.roads.accuracy`): train on the quadrant with the most labelled road,
score centerlines on the other three with buffer precision/recall at 1 m and 2 m. The
baseline is the survey's spectral-line classifier, run on the same images in the same run.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ingest.roads.accuracy import SAMPLES, evaluate_sample  # noqa: E402

DATA = REPO.parent / "shared" / "data" / "road_imagery"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", help="sample names to run")
    parser.add_argument("--data", type=Path, default=DATA)
    args = parser.parse_args()
    samples = [s for s in SAMPLES if not args.only or s.name in args.only]
    print(f"{'sample':18} {'classifier':10} {'P@1m':>6} {'R@1m':>6} {'P@2m':>6} {'R@2m':>6} "
          f"{'Q@2m':>6} {'seconds':>7}")
    totals: dict[str, list[float]] = {}
    for sample in samples:
        for classifier in ("spectral", "learned"):
            start = time.perf_counter()
            one, two = evaluate_sample(sample, args.data, classifier)
            seconds = time.perf_counter() - start
            print(f"{sample.name:18} {classifier:10} {one.precision:6.3f} {one.recall:6.3f} "
                  f"{two.precision:6.3f} {two.recall:6.3f} {two.quality:6.3f} {seconds:7.1f}",
                  flush=True)
            totals.setdefault(classifier, []).append((two.precision, two.recall))
    for classifier, rows in totals.items():
        p = sum(r[0] for r in rows) / len(rows)
        r = sum(r[1] for r in rows) / len(rows)
        print(f"mean @2m {classifier:10} precision {p:.3f} recall {r:.3f}")
    if "spectral" in totals and "learned" in totals:
        sp = sum(r[0] for r in totals["spectral"]) / len(totals["spectral"])
        le = sum(r[0] for r in totals["learned"]) / len(totals["learned"])
        print(f"learned / spectral precision @2m: {le / max(sp, 1e-9):.1f}x")


if __name__ == "__main__":
    main()
