"""A simulated re-survey of a stored network with a known answer, and its scoring: what
``bench/resurvey.py`` measures the matching on (the issue's recipe: 5 % of roads removed, 5 %
new roads, 5 % moved by 2-6 m, every line re-digitised with 0.3-1 m noise and another vertex
spacing, some lines split and some merged).

Why the conventions vary per line (noise, spacing, which side a road moves to, curvature of
new roads): a matching tuned on one convention of the generator would score well on it alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely import LineString, STRtree
from shapely.ops import linemerge, unary_union

from app.network.resurvey.matching import Matching, OldSegment


@dataclass
class Survey:
    """The re-survey's lines (metres) and the truth about every stored segment."""

    lines: list[np.ndarray]
    removed: set[int] = field(default_factory=set)
    moved: set[int] = field(default_factory=set)
    new: list[LineString] = field(default_factory=list)
    splits: int = 0
    merges: int = 0


def redigitise(line: LineString, rng: np.random.Generator) -> np.ndarray:
    """The line drawn again: vertices every 2-10 m, each off by 0.3-1 m (s.d., per line)."""
    spacing, noise = rng.uniform(2.0, 10.0), rng.uniform(0.3, 1.0)
    count = max(2, round(line.length / spacing) + 1)
    points = shapely.get_coordinates(shapely.line_interpolate_point(
        line, np.linspace(0, line.length, count)))
    return points + rng.normal(0, noise, points.shape)


def _new_road(base: LineString, olds: STRtree, taken: list[LineString],
              rng: np.random.Generator) -> LineString | None:
    """A road of 40-200 m leaving ``base`` at a right angle from 30-70 % along it, bending a
    little, farther than 15 m from every other road (so the answer is unambiguous)."""
    at = base.length * rng.uniform(0.3, 0.7)
    a, b = base.interpolate(at - 1), base.interpolate(at + 1)
    direction = np.array([b.y - a.y, a.x - b.x]) * rng.choice([-1, 1])
    direction /= np.hypot(*direction)
    length, bend = rng.uniform(40, 200), rng.uniform(-0.4, 0.4)
    start = np.array(base.interpolate(at).coords[0])
    turn = np.array([-direction[1], direction[0]])
    t = np.linspace(0, 1, 12)[:, None]
    road = LineString(start + t * length * direction + (t ** 2) * bend * length * turn)
    clear = road.buffer(15).difference(shapely.Point(start).buffer(20))
    if len(olds.query(clear, predicate="intersects")) or any(clear.intersects(r) for r in taken):
        return None
    return road


def simulate(segments: list[OldSegment], degree_two: list[tuple[int, int]],
             seed: int = 36, share: float = 0.05) -> Survey:
    """A re-survey of ``segments``: ``share`` removed, ``share`` moved (2-6 m, either side)
    and as many new roads, every line re-digitised; 10 % of the pairs ``degree_two`` (two
    segments meeting at a node of only them) drawn as one line, 10 % of the others split."""
    rng = np.random.default_rng(seed)
    n = len(segments)
    order = rng.permutation(n)
    count = round(share * n)
    survey = Survey([], removed={segments[i].id for i in order[:count]},
                    moved={segments[i].id for i in order[count:2 * count]})
    lines = {s.id: LineString(s.coords) for s in segments}
    drawn: dict[int, LineString] = {}
    for s in segments:
        if s.id in survey.removed:
            continue
        line = lines[s.id]
        if s.id in survey.moved:
            line = line.offset_curve(float(rng.uniform(2, 6) * rng.choice([-1, 1])))
        drawn[s.id] = line
    merged: set[int] = set()
    for a, b in degree_two:
        if a in drawn and b in drawn and not {a, b} & merged and rng.random() < 0.1 \
                and not {a, b} & survey.moved:
            joined = linemerge([drawn[a], drawn[b]])
            if joined.geom_type == "LineString":
                survey.lines.append(redigitise(joined, rng))
                merged |= {a, b}
                survey.merges += 1
    for sid, line in drawn.items():
        if sid in merged:
            continue
        if line.length > 30 and rng.random() < 0.1:
            cut = line.length * rng.uniform(0.3, 0.7)
            survey.lines += [redigitise(shapely.ops.substring(line, 0, cut), rng),
                             redigitise(shapely.ops.substring(line, cut, line.length), rng)]
            survey.splits += 1
        else:
            survey.lines.append(redigitise(line, rng))
    tree = STRtree(list(lines.values()))
    long = [lines[s.id] for s in segments if lines[s.id].length > 60]
    while len(survey.new) < count:
        road = _new_road(long[rng.integers(len(long))], tree, survey.new, rng)
        if road is not None:
            survey.new.append(road)
            survey.lines.append(redigitise(road, rng))
    return survey


@dataclass(frozen=True)
class Score:
    """Precision and recall of one kind of change."""

    kind: str
    proposed: int
    true: int
    precision: float
    recall: float


def _ratio(a: int, b: int) -> float:
    return a / b if b else 1.0


def outcomes(result: Matching) -> tuple[dict[int, str], list[LineString]]:
    """What a matching said of each segment (by id) and its new roads, as :func:`score`
    takes them."""
    said = {**{sid: "unchanged" for sid in result.unchanged},
            **{m.segment_id: "moved" for m in result.moved},
            **{m.segment_id: "missing" for m in result.missing}}
    return said, [LineString(r.coords) for r in result.new]


def score(segments: list[OldSegment], survey: Survey, said: dict[int, str],
          pieces: list[LineString], near_m: float = 5.0) -> list[Score]:
    """Per kind: of the segments proposed as moved / missing / unchanged (``said``; a segment
    not in it is unchanged), how many truly are (precision), and of those that truly are, how
    many were proposed (recall). A proposed new road (``pieces``) is right when most of it
    lies within ``near_m`` of a true new road; a true new road is found when most of it lies
    within ``near_m`` of proposed ones."""
    truth = {s.id: "missing" if s.id in survey.removed else
             "moved" if s.id in survey.moved else "unchanged" for s in segments}
    scores = []
    for kind in ("unchanged", "moved", "missing"):
        proposed = {sid for sid in truth if said.get(sid, "unchanged") == kind}
        true = {sid for sid, k in truth.items() if k == kind}
        scores.append(Score(kind, len(proposed), len(true),
                            _ratio(len(proposed & true), len(proposed)),
                            _ratio(len(proposed & true), len(true))))
    truth_zone = unary_union(survey.new).buffer(near_m) if survey.new else None
    found_zone = unary_union(pieces).buffer(near_m) if pieces else None
    right = sum(1 for p in pieces if truth_zone is not None
                and p.intersection(truth_zone).length > 0.5 * p.length)
    found = sum(1 for t in survey.new if found_zone is not None
                and t.intersection(found_zone).length > 0.5 * t.length)
    scores.append(Score("new", len(pieces), len(survey.new), _ratio(right, len(pieces)),
                        _ratio(found, len(survey.new))))
    return scores
