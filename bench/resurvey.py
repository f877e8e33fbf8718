"""Benchmark: a re-survey matched against the network it re-surveys (issue 36), same run.

1. **Andorra, simulated re-survey.** The Andorra OSM extract is imported as "the map" and 50
   segments get a person's edit (name and speed, through the editing API's code). A
   re-survey is simulated from it (:mod:`testkit.resurvey`: 5 % of roads removed, 5 % new
   roads, 5 % moved by 2-6 m, every line re-digitised with 0.3-1 m noise and 2-10 m vertex
   spacing, 10 % of lines split, 10 % of degree-2 pairs merged) and proposed as a change set
   (``propose``: what ``--update`` runs). Printed: precision / recall per kind (target
   >= 0.95), then every proposal accepted in bulk ("all"): ids of the unchanged roads kept
   (target >= 99 %), human edits kept (target 100 %), topology valid; the time of the
   update against the baseline of replacing the network with the same lines (``--replace``,
   which keeps nothing). ``--seed N`` draws another re-survey. Then the unchanged extract
   over itself: what a re-survey that changed nothing proposes.
2. **SpaceNet Vegas, real.** The truth centrelines of the Vegas image as the map, the roads
   extracted from the same image (layer ``vegas``, the road model zero-shot) as the survey
   (``ingest roads --update``): what the matching proposes, and how much of the truth each
   kind covers.

Run: ``.venv/bin/python bench/resurvey.py [--seed N]`` (uses DATABASE_URL or the embedded
cluster; creates and drops a throwaway database).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from shapely import LineString
from sqlalchemy import text

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.network.resurvey.frame import LocalFrame
from app.network.resurvey.matching import OldSegment
from testkit.resurvey import score, simulate

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
ANDORRA = SHARED / "osm" / "andorra.osm.pbf"
VEGAS = SHARED / "road_imagery" / "spacenet_vegas"
TARGET = 0.95
IDS_KEPT = 0.99
EDITS = 50


def stored_segments(session: Any, network_id: int) -> tuple[list[OldSegment], LocalFrame,
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
    pairs = [(ids[0], ids[1]) for ids in at.values() if len(ids) == 2 and ids[0] != ids[1]]
    return segments, frame, pairs


def human_edits(session: Any, name: str, ids: list[int]) -> dict[int, tuple]:
    """A person's edit of each segment (PATCH name and speed, as the web map sends it); the
    state each was left in: (name, speed, geometry as WKT)."""
    from app.network import collections as colls
    from app.network import crs as crs_
    from app.network.resurvey.changes import network
    from app.network.segment_editing import patch_segment
    from app.network.tokens import Principal

    c: colls.Collection = network(session, name)
    person = Principal("surveyor", "editor")
    for i, fid in enumerate(ids):
        patch_segment(session, c, fid, None, {"name": f"Checked {i}", "speed_limit_kph": 30},
                      crs_.DEFAULT, person)
    return _states(session, ids)


def _states(session: Any, ids: list[int]) -> dict[int, tuple]:
    rows = session.execute(text("SELECT id, name, speed_limit_kph, ST_AsText(geom) FROM "
                                "road_segments WHERE id = ANY(:ids)"), {"ids": ids}).all()
    return {r[0]: tuple(r[1:]) for r in rows}


def proposals(session: Any, set_id: int, frame: LocalFrame
              ) -> tuple[dict[int, str], list[LineString]]:
    """What the stored change set says of each segment, and its new roads (local frame)."""
    rows = session.execute(text(
        "SELECT kind, segment_id, ST_AsGeoJSON(geom)::json->'coordinates' FROM "
        "proposed_changes WHERE change_set_id = :s"), {"s": set_id}).all()
    said = {r[1]: r[0] for r in rows if r[1] is not None}
    return said, [LineString(frame.metres(r[2])) for r in rows if r[0] == "new"]


def andorra(seed: int) -> None:
    """Part 1: Andorra as the map, a simulated re-survey of it, scored per kind, accepted."""
    from app.db.session import session_scope
    from app.network.resurvey.changes import Selection, SurveyLine, accept, propose
    from app.network.tokens import Principal
    from cli.ops.network_integrity import check_network
    from ingest.network import RoadLine, import_network, write_network

    with session_scope() as session:
        import_network(session, ANDORRA, "andorra-again")
        summary = import_network(session, ANDORRA, "andorra")
        segments, frame, pairs = stored_segments(session, summary.network_id)
        rng = np.random.default_rng(seed + 1)
        edited = sorted(int(i) for i in rng.choice([s.id for s in segments], EDITS,
                                                   replace=False))
        after_edit = human_edits(session, "andorra", edited)
    survey = simulate(segments, pairs, seed=seed)
    lonlat = [frame.lonlat(line) for line in survey.lines]
    lines = [SurveyLine([tuple(p) for p in c], {"road_class": "residential"})  # type: ignore[misc]
             for c in lonlat]
    removed_or_moved = len(set(edited) & (survey.removed | survey.moved))
    print(f"Andorra: {len(segments):,} segments, {EDITS} edited by a person "
          f"({removed_or_moved} of them removed or moved in the re-survey); re-survey of "
          f"{len(survey.lines):,} lines ({len(survey.removed)} removed, {len(survey.moved)} "
          f"moved, {len(survey.new)} new, {survey.splits} split, {survey.merges} merged; "
          f"seed {seed})")
    start = time.perf_counter()
    with session_scope() as session:
        proposed = propose(session, "andorra", lines, source="file:simulated",
                           coverage=None, principal=Principal("bench", "admin"))
    update_s = time.perf_counter() - start
    with session_scope() as session:
        said, pieces = proposals(session, proposed["id"], frame)
    print(f"{'kind':<10}{'proposed':>9}{'true':>6}{'precision':>10}{'recall':>8}  verdict")
    for s in score(segments, survey, said, pieces):
        ok = s.precision >= TARGET and s.recall >= TARGET
        print(f"{s.kind:<10}{s.proposed:>9}{s.true:>6}{s.precision:>10.3f}{s.recall:>8.3f}  "
              f"{'meets' if ok else 'MISSES'} >= {TARGET}")
    start = time.perf_counter()
    with session_scope() as session:
        decided = accept(session, "andorra", proposed["id"], Selection(),
                         Principal("reviewer", "editor"))
    accept_s = time.perf_counter() - start
    unchanged = [s.id for s in segments if s.id not in survey.removed | survey.moved]
    with session_scope() as session:
        alive = set(session.execute(text("SELECT id FROM road_segments WHERE id = ANY(:ids)"),
                                    {"ids": unchanged}).scalars())
        kept_edits = sum(1 for fid, state in _states(session, edited).items()
                         if after_edit.get(fid) == state)
        report = check_network(session, "andorra")
    ids_kept = len(alive) / len(unchanged)
    print(f"accept all: {decided} in {accept_s:.1f} s; topology "
          f"{'valid' if report.ok else 'BROKEN'}")
    print(f"ids of unchanged roads kept: {ids_kept:.4f} "
          f"({'meets' if ids_kept >= IDS_KEPT else 'MISSES'} >= {IDS_KEPT}); human edits kept: "
          f"{kept_edits}/{EDITS} ({'meets' if kept_edits == EDITS else 'MISSES'} 100 %)")
    start = time.perf_counter()
    with session_scope() as session:
        write_network(session, "andorra-replaced", [RoadLine([tuple(p) for p in c])
                                                    for c in lonlat])
    replace_s = time.perf_counter() - start
    print(f"time: update (match + store the change set) {update_s:.1f} s vs replacing the "
          f"network with the same lines {replace_s:.1f} s ({update_s / replace_s:.1f}x; the "
          f"replace keeps no id, edit or history)")


def same_again() -> None:
    """The Andorra extract again over the network imported from it: what a re-survey that
    changed nothing proposes (a baseline for the false alarms)."""
    from app.db.session import session_scope
    from ingest.network.update import update_from_file

    start = time.perf_counter()
    with session_scope() as session:
        proposed = update_from_file(session, ANDORRA, "andorra-again")
    print(f"the same extract again: {proposed['counts']} in {time.perf_counter() - start:.1f} s")


def vegas() -> None:
    """Part 2: the SpaceNet truth as the map, the roads extracted from its image as survey."""
    from app.db.session import session_scope
    from ingest.network import import_network
    from ingest.raster.job import ingest_raster
    from ingest.roads.layer import ingest_layer_roads
    from ingest.roads.pipeline import ExtractParams

    truth = VEGAS / "AOI_2_Vegas_img0.geojson"
    image = VEGAS / "RGB-PanSharpen_AOI_2_Vegas_img0.tif"
    if not truth.exists() or not image.exists():
        print(f"SpaceNet Vegas: skipped, {VEGAS} is absent")
        return
    ingest_raster([image], "vegas")
    with session_scope() as session:
        summary = import_network(session, truth, "vegas")
    start = time.perf_counter()
    with session_scope() as session:
        done = ingest_layer_roads(session, "vegas", "vegas", None, ExtractParams(), update=True)
    took = time.perf_counter() - start
    assert done.change_set is not None
    with session_scope() as session:
        rows = session.execute(text(
            "SELECT kind, count(*), sum(ST_Length(geom::geography)) FROM proposed_changes "
            "WHERE change_set_id = :s GROUP BY kind ORDER BY kind"),
            {"s": done.change_set["id"]}).all()
    counts = done.change_set["counts"]
    print(f"SpaceNet Vegas img0: truth {summary.segments} segments "
          f"({summary.total_length_m / 1000:.2f} km) as the map, {len(done.stored)} lines "
          f"extracted zero-shot as the survey ({took:.1f} s with the extraction)")
    print("  outcome per truth segment: " + ", ".join(f"{n} {k}" for k, n in counts.items()))
    for kind, n, metres in rows:
        print(f"  proposed {kind}: {n} ({metres / 1000:.2f} km)")


def main() -> None:
    """Both parts, in a throwaway database."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, default=36, help="seed of the simulated survey")
    args = parser.parse_args()
    from testkit.scratch import bench_database

    with bench_database("ugvmap_resurvey"):
        andorra(args.seed)
        same_again()
        vegas()


if __name__ == "__main__":
    main()
