"""Centreline geometry and topology of extracted roads, before and after issue 20, one run.

    .venv/bin/python bench/roads_geometry.py [--only massachusetts_01 ...] [--no-ipm]

*before* is the pixel-chain geometry (skeleton pixels, Ramer-Douglas-Peucker at 0.5 m:
``GraphParams(geometry="pixel", simplify_m=0.5)``), rebuilt in this run from the same
skeleton and mask as *after* (the default ``ridge`` geometry), so the two differ only in
the geometry and graph steps.

1. The shared validation images (``shared/data/road_imagery``, the protocol of
   :mod:`testkit.roads_accuracy`, zero-shot model): share of 1 m steps turning by more than
   10° / 20° (every line resampled every 1 m), buffer precision/recall at 1 m and 2 m and
   APLS on the three scored quadrants, connected pieces (8-connected components of the
   rasterised centrelines) against the truth's, and junction precision/recall (nodes of
   degree >= 3 within 5 m of a true junction: the truth's lines noded, ends shared by three
   or more lines), and dead ends away from the image border (nodes of degree 1 more than
   10 m inside it) against the truth's (ends of its noded lines that no other line shares),
   with the share of them within 10 m of a true road end: a dead end should be where a road
   ends, not where the model lost it.
2. A synthetic IPM drive: a 0.06 m top-down mosaic of the ``ingest.ipm.synthetic`` road
   (7 m wide, edge lines, dashed centre line) along 320° of a ring, covered only within
   9 m of the vehicle's path, so 40° of the ring (about 11 m of road) was never seen; the
   trajectory is the road sample (as ``ingest roads`` on an ipm-mosaic layer gives it) and
   every parameter is a default. Measures: the centreline's median / 95th percentile /
   maximum distance to the true centre, the share of the driven road with a centreline
   within 1 m, and the length drawn where the drive saw nothing.

Targets (issue 20): real imagery <= 3 % of 1 m steps turning > 10° with P/R at 2 m no lower
than before; IPM drive median <= 0.10 m, p95 <= 0.3 m, max <= 1.5 m, >= 90 % covered.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import shapely
from scipy.spatial import cKDTree

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ingest.roads.curve import arc_length  # noqa: E402
from ingest.roads.evaluate import rasterize_lines, turn_share  # noqa: E402
from ingest.roads.graph import GraphParams, RoadGraph, build_graph  # noqa: E402
from ingest.roads.pipeline import Extraction, ExtractParams, extract_roads  # noqa: E402
from ingest.roads.synthetic import IpmScene, ipm_scene  # noqa: E402
from testkit.roads_accuracy import SAMPLES, load_sample, score_lines  # noqa: E402

DATA = REPO.parent / "shared" / "data" / "road_imagery"
BEFORE = GraphParams(geometry="pixel", simplify_m=0.5)
JUNCTION_M = 5.0
DEAD_END_M = 10.0
"""A dead end this close to a true road end is right; one this close to the image border is
where the road leaves the image, and is not counted."""
MIN_PIECE_M = 10.0
"""Rasterised pieces shorter than this (in pixels' worth of metres) are not counted."""


def graph_lines(graph: RoadGraph, extraction: Extraction) -> list[np.ndarray]:
    """Edges of ``graph`` (on the extraction's working grid) in source pixel coordinates."""
    to_source = extraction.frame.to_source
    return [np.column_stack(to_source @ (e.coords[:, 0], e.coords[:, 1])) for e in graph.edges]


def junction_points(graph: RoadGraph, extraction: Extraction) -> np.ndarray:
    """Source-pixel positions of the graph's nodes of degree >= 3."""
    pts = [n.xy for n in graph.nodes if n.is_junction]
    if not pts:
        return np.empty((0, 2))
    xy = np.asarray(pts, float)
    return np.column_stack(extraction.frame.to_source @ (xy[:, 0], xy[:, 1]))


def _noded_ends(lines: list[np.ndarray]) -> dict[tuple[float, float], int]:
    """How many of the noded truth lines end at each end point."""
    noded = shapely.node(shapely.MultiLineString([ln for ln in lines if len(ln) >= 2]))
    ends: dict[tuple[float, float], int] = {}
    for part in shapely.get_parts(noded):
        c = shapely.get_coordinates(part)
        for p in (c[0], c[-1]):
            key = (round(float(p[0]), 3), round(float(p[1]), 3))
            ends[key] = ends.get(key, 0) + 1
    return ends


def truth_dead_ends(lines: list[np.ndarray]) -> np.ndarray:
    """Ends of the noded truth lines that no other line shares (source pixels)."""
    return np.array([k for k, n in _noded_ends(lines).items() if n == 1], float).reshape(-1, 2)


def inside(pts: np.ndarray, shape: tuple[int, int], margin_px: float) -> np.ndarray:
    """Points (x, y) more than ``margin_px`` inside a ``shape`` image."""
    return ((pts[:, 0] > margin_px) & (pts[:, 1] > margin_px)
            & (pts[:, 0] < shape[1] - margin_px) & (pts[:, 1] < shape[0] - margin_px))


def dead_ends(graph: RoadGraph, extraction: Extraction) -> np.ndarray:
    """Source-pixel positions of the graph's nodes of degree 1."""
    xy = np.asarray([n.xy for n in graph.nodes if n.degree == 1], float).reshape(-1, 2)
    return np.column_stack(extraction.frame.to_source @ (xy[:, 0], xy[:, 1]))


def truth_junctions(lines: list[np.ndarray]) -> np.ndarray:
    """Points where three or more truth lines meet, after noding them (crossings count)."""
    ends = _noded_ends(lines)
    pts = np.array([k for k, n in ends.items() if n >= 3], float).reshape(-1, 2)
    if len(pts) < 2:
        return pts
    # One crossing drawn as several nearby nodes is one junction.
    groups = cKDTree(pts).query_ball_point(pts, JUNCTION_M / 2)
    seen, out = set(), []
    for i, group in enumerate(groups):
        if i not in seen:
            seen.update(group)
            out.append(pts[group].mean(axis=0))
    return np.array(out)


def matched_share(a: np.ndarray, b: np.ndarray, radius: float) -> float:
    """Share of points ``a`` with a point of ``b`` within ``radius`` (NaN if ``a`` is empty)."""
    if len(a) == 0:
        return math.nan
    if len(b) == 0:
        return 0.0
    d, _ = cKDTree(b).query(a)
    return float((d <= radius).mean())


def pieces(lines: list[np.ndarray], shape: tuple[int, int], resolution_m: float) -> int:
    """Connected pieces of the rasterised lines, ignoring crumbs under ``MIN_PIECE_M``."""
    raster = rasterize_lines(lines, shape).astype(np.uint8)
    raster = cv2.dilate(raster, np.ones((3, 3), np.uint8))
    _n, _, stats, _ = cv2.connectedComponentsWithStats(raster, connectivity=8)
    size = np.maximum(stats[1:, cv2.CC_STAT_WIDTH], stats[1:, cv2.CC_STAT_HEIGHT])
    return int((size * resolution_m >= MIN_PIECE_M).sum())


@dataclass
class Row:
    """One line of the real-imagery table."""

    turn10: float
    turn20: float
    p1: float
    r1: float
    p2: float
    r2: float
    apls: float
    pieces: int
    truth_pieces: int
    jp: float
    jr: float
    dead: int
    truth_dead: int
    dead_at_end: float


def real_rows(names: list[str] | None) -> dict[str, dict[str, Row]]:
    """Before/after rows per validation image."""
    out: dict[str, dict[str, Row]] = {}
    for sample in SAMPLES:
        if names and sample.name not in names:
            continue
        image, truth = load_sample(sample, DATA)
        res = image.resolution_m
        start = time.perf_counter()
        after = extract_roads(image, None, ExtractParams(classifier="model"))
        seconds = time.perf_counter() - start
        stages = after.stages
        before = build_graph(stages["topology"], stages["houses_removed"],
                             after.frame.resolution_m, BEFORE)
        true_junctions = truth_junctions(truth.lines) * res
        truth_pieces = pieces(truth.lines, truth.road.shape, res)
        border = DEAD_END_M / res
        true_ends = truth_dead_ends(truth.lines)
        true_ends = true_ends[inside(true_ends, truth.road.shape, border)]
        rows = {}
        for name, graph in (("before", before), ("after", after.graph)):
            lines = graph_lines(graph, after)
            ev = score_lines(truth, lines, seconds)
            one, two = ev.scores
            junctions = junction_points(graph, after) * res
            ends = dead_ends(graph, after)
            ends = ends[inside(ends, truth.road.shape, border)]
            rows[name] = Row(
                turn_share([ln * res for ln in lines], 1.0, 10.0)[0],
                turn_share([ln * res for ln in lines], 1.0, 20.0)[0],
                one.precision, one.recall, two.precision, two.recall, ev.apls,
                pieces(lines, truth.road.shape, res), truth_pieces,
                matched_share(junctions, true_junctions, JUNCTION_M),
                matched_share(true_junctions, junctions, JUNCTION_M),
                len(ends), len(true_ends), matched_share(ends * res, true_ends * res, DEAD_END_M))
            print(f"| {sample.name:18} | {name:6} | " + _cells(rows[name]) + " |", flush=True)
        out[sample.name] = rows
    return out


def _cells(r: Row) -> str:
    return (f"{r.turn10 * 100:5.1f} % | {r.turn20 * 100:5.1f} % | {r.p1:.3f} | {r.r1:.3f} | "
            f"{r.p2:.3f} | {r.r2:.3f} | {r.apls:.3f} | {r.pieces:3d} / {r.truth_pieces:3d} | "
            f"{r.jp:.2f} | {r.jr:.2f} | {r.dead:3d} / {r.truth_dead:3d} | {r.dead_at_end:.2f}")


# --- the synthetic IPM drive ----------------------------------------------------------------

def ipm_rows(scene: IpmScene) -> dict[str, dict[str, float]]:
    """Before/after measures on the synthetic drive, defaults only."""
    start = time.perf_counter()
    after = extract_roads(scene.image, scene.labels)
    seconds = time.perf_counter() - start
    stages = after.stages
    before = build_graph(stages["topology"], stages["houses_removed"], after.frame.resolution_m,
                         BEFORE)
    truth_az = np.arange(0, 2 * math.pi, 0.1 / scene.centre_radius_m)
    truth_pts = scene.centre_radius_m * np.column_stack([np.sin(truth_az), np.cos(truth_az)])
    col, row = ~scene.transform @ (truth_pts[:, 0], truth_pts[:, 1])
    truth_pts = truth_pts[scene.coverage[row.astype(int), col.astype(int)]]
    out = {}
    for name, graph in (("before", before), ("after", after.graph)):
        lines = [np.column_stack(after.frame.to_output @ (e.coords[:, 0], e.coords[:, 1]))
                 for e in graph.edges]
        dense = [_densify(ln, 0.05) for ln in lines]
        pts = np.vstack(dense) if dense else np.empty((0, 2))
        dist = scene.truth_distance(pts) if len(pts) else np.array([np.inf])
        col, row = ~scene.transform @ (pts[:, 0], pts[:, 1])
        h, w = scene.coverage.shape
        r, c = np.floor(row).astype(int), np.floor(col).astype(int)
        on = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        seen = np.zeros(len(pts), bool)
        seen[on] = scene.coverage[r[on], c[on]]
        out[name] = {
            "turn10": turn_share(lines, 1.0, 10.0)[0], "turn20": turn_share(lines, 1.0, 20.0)[0],
            "median": float(np.median(dist)), "p95": float(np.percentile(dist, 95)),
            "max": float(dist.max()),
            "covered": matched_share(truth_pts, pts, 1.0) if len(pts) else 0.0,
            "unseen_m": float((~seen).sum() * 0.05), "pieces": _components(graph),
            "edges": len(graph.edges), "seconds": seconds}
    return out


def _densify(line: np.ndarray, step: float) -> np.ndarray:
    cum = arc_length(line)
    s = np.arange(0.0, cum[-1] + step / 2, step)
    return np.column_stack([np.interp(s, cum, line[:, 0]), np.interp(s, cum, line[:, 1])])


def _components(graph: RoadGraph) -> int:
    import networkx as nx

    g = nx.Graph()
    g.add_nodes_from(n.id for n in graph.nodes)
    g.add_edges_from((e.source, e.target) for e in graph.edges)
    return nx.number_connected_components(g)


def main() -> None:
    """Print both tables and the target checks."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", help="validation sample names to run")
    parser.add_argument("--no-ipm", action="store_true", help="skip the synthetic IPM drive")
    parser.add_argument("--no-real", action="store_true", help="skip the validation images")
    args = parser.parse_args()
    if not args.no_real:
        print("| sample | geometry | turn > 10° | turn > 20° | P@1m | R@1m | P@2m | R@2m | APLS | "
              "pieces / truth | junction P | junction R | dead ends / truth | at a road end |")
        print("|" + "---|" * 14)
        rows = real_rows(args.only)
        mean = {}
        for name in ("before", "after"):
            cols = [r[name] for r in rows.values()]
            m = Row(*(float(np.nanmean([getattr(c, f) for c in cols]))
                      for f in Row.__dataclass_fields__))
            mean[name] = m
            print(f"| **mean** ({len(cols)} images) | {name} | "
                  f"{m.turn10 * 100:5.1f} % | {m.turn20 * 100:5.1f} % | {m.p1:.3f} | {m.r1:.3f} | "
                  f"{m.p2:.3f} | {m.r2:.3f} | {m.apls:.3f} | {m.pieces:.1f} / {m.truth_pieces:.1f}"
                  f" | {m.jp:.2f} | {m.jr:.2f} | {m.dead:.1f} / {m.truth_dead:.1f} | "
                  f"{m.dead_at_end:.2f} |")
        b, a = mean["before"], mean["after"]
        ok = a.turn10 <= 0.03 and a.p2 >= b.p2 - 1e-9 and a.r2 >= b.r2 - 1e-9
        print(f"real imagery target (<= 3 % of 1 m steps turn > 10°, P/R@2m not lower): "
              f"{'met' if ok else 'MISSED'} (turn > 10°: {b.turn10 * 100:.1f} % -> "
              f"{a.turn10 * 100:.1f} %, ratio {a.turn10 / max(b.turn10, 1e-9):.3f})")
    if not args.no_ipm:
        scene = ipm_scene()
        print(f"\nsynthetic IPM drive: {scene.image.pixels.shape[1]} x "
              f"{scene.image.pixels.shape[0]} px at {scene.image.resolution_m} m/px, "
              f"{scene.coverage.mean() * 100:.0f} % covered")
        print("| geometry | turn > 10° | turn > 20° | median m | p95 m | max m | covered | "
              "drawn unseen m | pieces | edges | seconds |")
        print("|" + "---|" * 11)
        result = ipm_rows(scene)
        for name, r in result.items():
            print(f"| {name} | {r['turn10'] * 100:5.1f} % | {r['turn20'] * 100:5.1f} % | "
                  f"{r['median']:.3f} | {r['p95']:.3f} | {r['max']:.3f} | "
                  f"{r['covered'] * 100:.1f} % | {r['unseen_m']:.1f} | {r['pieces']} | "
                  f"{r['edges']} | {r['seconds']:.1f} |")
        a = result["after"]
        ok = (a["median"] <= 0.10 and a["p95"] <= 0.3 and a["max"] <= 1.5
              and a["covered"] >= 0.9)
        print(f"IPM target (median <= 0.10, p95 <= 0.3, max <= 1.5 m, >= 90 % covered): "
              f"{'met' if ok else 'MISSED'} (median ratio after/before "
              f"{a['median'] / max(result['before']['median'], 1e-9):.2f})")


if __name__ == "__main__":
    main()
