"""Match a re-survey (new lines) against a stored network (old segments): which roads are
unchanged, moved, new or missing. Pure functions of coordinates in metres (a local frame,
:mod:`app.network.resurvey.frame`), no database.

Why samples and not whole-line comparisons: a re-survey is digitised afresh, so its lines
neither start nor end where the stored segments do: one old segment may be covered by two
new lines (split by a junction the new data has), one new line may run over three old ones
(merged through nodes the new data lacks), and a new line may carry on past an old segment
(a road extended). Measuring both sides every :attr:`Tolerances.step_m` metres and asking,
per sample, "is there a road of the other side here, running the same way?" handles all of
these the same way, as RoadMatcher's and Hootenanny's "partial matching" does.

A sample of one side is *seen* on the other side when a line of the other side:

- passes within :attr:`Tolerances.match_m` of it, at a foot point strictly inside that line
  (a road that merely continues beyond the sample's end is nearest at its own end: that is
  the next road, not this one seen again);
- runs the same way there, within :attr:`Tolerances.heading_deg` (ignoring direction): a
  crossing road at a junction is not the same road;
- is not nearer (by more than :attr:`Tolerances.rival_m`) to another line of the sample's own
  side running the same way at that foot point: of two parallel roads (a dual carriageway)
  each new line is seen by the old road it lies on, so one of them removed is not explained
  by the other.

Outcomes, per old segment, from the share of its samples (inside the new data's coverage)
that are seen: at least :attr:`Tolerances.matched_share` -> matched, *unchanged* when the
median distance of its seen samples is at most :attr:`Tolerances.moved_m`, else *moved*
(proposed geometry: the feet on the new lines, between the segment's own end nodes, so the
topology stays); less -> *missing*. A segment with less than half its samples inside the
coverage is *unseen*: outside the new imagery nothing is said. Per new line, each run of
unseen samples at least :attr:`Tolerances.new_min_m` long is a *new* road, its ends joined to
the network where they meet it (see :func:`new_pieces`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely import LineString, Polygon, STRtree
from shapely.geometry.base import BaseGeometry
from shapely.ops import substring

Coords = np.ndarray
"""(n, 2) float array of x, y in metres."""


@dataclass(frozen=True)
class Tolerances:
    """How near and how aligned a road of the re-survey must be to be a stored road seen
    again. Defaults fit a re-survey of 0.3-1 m noise whose roads may have moved by up to ~6 m
    (``bench/resurvey.py``); every one is an option of ``--update``."""

    match_m: float = 10.0
    """A line of the other side farther than this from a sample does not see it."""
    heading_deg: float = 35.0
    """Largest angle between the two roads' directions at a sample (either way round)."""
    moved_m: float = 1.7
    """A matched segment whose seen samples lie, at the median, farther than this to one side
    of the new lines has moved. Noise cancels out in the signed median, but a re-digitised
    curve with vertices 10 m apart cuts its bends by up to ~1.5 m (on Andorra's hairpins),
    and a road moved 2 m measures from ~1.6 m on such bends: 1.7 m splits the two."""
    matched_share: float = 0.5
    """Share of a segment's samples (inside the coverage) that must be seen for it to be
    matched; below it, the segment is missing."""
    new_min_m: float = 8.0
    """A stretch of a new line unseen by the network must be this long to be a new road (a
    shorter one is the wobble of a line where it joins a junction)."""
    step_m: float = 2.0
    """Distance between samples along a line."""
    join_m: float = 3.0
    """A new road's own end this near the network is joined to it (a T junction)."""
    node_m: float = 5.0
    """A new road's end joins an existing node this near rather than the road's side."""
    rival_m: float = 2.0
    """A sample is the other's only if no line of its own side is this much nearer there."""
    direction_m: float = 4.0
    """Half the stretch of line over which a direction is measured (noise averages out)."""

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"tolerance {name} must be a positive number, not {value!r}")
        if self.matched_share > 1:
            raise ValueError("tolerance matched_share must be at most 1")
        if self.heading_deg >= 90:
            raise ValueError("tolerance heading_deg must be below 90")


@dataclass(frozen=True)
class OldSegment:
    """A stored segment: its id, its line in the local frame, and whether a person created or
    edited it (then no change of it is accepted without a look at it alone)."""

    id: int
    coords: Coords
    edited: bool = False


@dataclass(frozen=True)
class Moved:
    """A matched segment whose road lies elsewhere now: a proposed new line for it."""

    segment_id: int
    offset_m: float
    """Median signed distance of the seen samples to the new lines, as a magnitude:
    digitising noise falls either side and cancels out, a moved road lies all to one side."""
    seen_share: float
    coords: Coords
    """The proposed line: the segment's own ends, and between them the new lines' course."""
    edited: bool


@dataclass(frozen=True)
class Missing:
    """A segment inside the coverage that the re-survey does not show: flagged, never
    deleted without review."""

    segment_id: int
    seen_share: float
    edited: bool


@dataclass(frozen=True)
class NewRoad:
    """A stretch of the re-survey no stored segment explains: a proposed segment."""

    line: int
    """Index of the new line this stretch is cut from (its attributes are that line's)."""
    coords: Coords
    joins: tuple[int | None, int | None]
    """The old segment each end was joined to (None: a free end); :func:`new_pieces` gives
    their indices, :func:`match` their ids."""


@dataclass
class Matching:
    """The outcome for every old segment (by id) and the new roads."""

    unchanged: dict[int, float] = field(default_factory=dict)
    """Segment id -> median (signed) offset of its seen samples (m)."""
    moved: list[Moved] = field(default_factory=list)
    missing: list[Missing] = field(default_factory=list)
    new: list[NewRoad] = field(default_factory=list)
    unseen: list[int] = field(default_factory=list)
    """Segments mostly outside the coverage: nothing is said of them."""

    def counts(self) -> dict[str, int]:
        """How many of each outcome (what a change set records)."""
        return {"unchanged": len(self.unchanged), "moved": len(self.moved),
                "new": len(self.new), "missing": len(self.missing), "unseen": len(self.unseen)}


class _Edges:
    """Lines as a table of their straight pieces (vertex to vertex), so that sampling,
    projecting a point and measuring a direction are numpy over all lines at once: shapely's
    per-line interpolation walks every vertex of the line on each call, which on Andorra's
    long mountain roads took minutes instead of seconds."""

    def __init__(self, lines: Sequence[Coords]) -> None:
        coords = [np.asarray(c, float)[:, :2] for c in lines]
        counts = np.array([len(c) for c in coords], int)
        xy = np.concatenate(coords) if coords else np.zeros((0, 2))
        line_of = np.repeat(np.arange(len(coords)), counts)
        step = np.hypot(*np.diff(xy, axis=0).T) if len(xy) else np.zeros(0)
        same = line_of[1:] == line_of[:-1] if len(xy) else np.zeros(0, bool)
        step = np.where(same, step, 0.0)
        # Distance along the line of every vertex, and a global, increasing version of it
        # (each line placed after the previous one, 1 m apart) for one searchsorted.
        cum = np.concatenate([[0.0], np.cumsum(step)]) if len(xy) else np.zeros(0)
        first = np.cumsum(counts) - counts
        self.along = cum - cum[first][line_of] if len(xy) else cum
        self.length = self.along[first + counts - 1] if len(xy) else np.zeros(0)
        self.base = np.concatenate([[0.0], np.cumsum(self.length + 1.0)])[:-1]
        self.key = self.along + self.base[line_of]
        self.xy = xy
        pieces = np.flatnonzero(same & (step > 0))
        self.start, self.end = xy[pieces], xy[pieces + 1]
        self.piece_line, self.piece_along = line_of[pieces], self.along[pieces]
        self.tree = STRtree(shapely.linestrings(np.stack([self.start, self.end], 1)))

    def at(self, line: np.ndarray, along: np.ndarray) -> np.ndarray:
        """(n, 2) positions ``along`` (clipped to the line) on lines ``line``."""
        along = np.clip(along, 0, self.length[line])
        key = along + self.base[line]
        return np.column_stack([np.interp(key, self.key, self.xy[:, 0]),
                                np.interp(key, self.key, self.xy[:, 1])])

    def project(self, xy: np.ndarray, pieces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(foot points, fraction along the piece) of points ``xy`` on ``pieces``."""
        a, ab = self.start[pieces], self.end[pieces] - self.start[pieces]
        t = np.clip(np.sum((xy - a) * ab, 1) / np.sum(ab * ab, 1), 0, 1)
        return a + t[:, None] * ab, t

    def nearest(self, xy: np.ndarray, reach: float, direction: np.ndarray, cos_min: float
                ) -> np.ndarray:
        """Distance from each point to the nearest line running along ``direction`` there
        (within the angle whose cosine is ``cos_min``; inf beyond ``reach``): one query of the
        pieces' tree for all points (a nearest-neighbour query per point is ~10x slower)."""
        out = np.full(len(xy), np.inf)
        pi, ei = self.tree.query(shapely.points(xy), predicate="dwithin", distance=reach)
        foot, _ = self.project(xy[pi], ei)
        along = self.end[ei] - self.start[ei]
        cos = np.abs(np.sum(along * direction[pi], 1)) / np.hypot(*along.T)
        aligned = cos >= cos_min
        np.minimum.at(out, pi[aligned], np.hypot(*(xy[pi] - foot).T)[aligned])
        return out

    def direction(self, line: np.ndarray, along: np.ndarray, half: float) -> np.ndarray:
        """Unit direction of each line at ``along``, over the stretch ``along +- half``."""
        d = self.at(line, along + half) - self.at(line, along - half)
        norm = np.hypot(d[:, 0], d[:, 1])
        return d / np.where(norm > 0, norm, 1)[:, None]


@dataclass(frozen=True)
class _Samples:
    """Points every ``step_m`` along lines: owner line, distance along it, unit direction."""

    owner: np.ndarray
    along: np.ndarray
    xy: np.ndarray
    direction: np.ndarray


def _sample(edges: _Edges, tol: Tolerances) -> _Samples:
    """At least three samples per line, evenly spaced, none at its very ends (where every
    road meets its neighbours)."""
    lengths = edges.length
    counts = np.maximum(3, np.ceil(lengths / tol.step_m)).astype(int)
    owner = np.repeat(np.arange(len(lengths)), counts)
    starts = np.cumsum(counts) - counts
    rank = np.arange(len(owner)) - np.repeat(starts, counts)
    along = (rank + 0.5) * lengths[owner] / counts[owner]
    return _Samples(owner, along, edges.at(owner, along),
                    edges.direction(owner, along, tol.direction_m))


def _seen(samples: _Samples, own: _Edges, other: _Edges, tol: Tolerances
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each sample of lines ``own``: the line of ``other`` that sees it (-1: none), the
    signed distance to it (positive: to the left of the sample's line) and the foot point
    on it (x, y) (see the module's rules)."""
    n = len(samples.owner)
    best = np.full(n, -1)
    dist = np.full(n, np.inf)
    feet = np.full((n, 2), np.nan)
    if not len(other.start) or not n:
        return best, dist, feet
    pi, ei = other.tree.query(shapely.points(samples.xy), predicate="dwithin",
                              distance=tol.match_m)
    if not len(pi):
        return best, dist, feet
    p = samples.xy[pi]
    foot, t = other.project(p, ei)
    d = np.hypot(*(p - foot).T)
    li = other.piece_line[ei]
    at = other.piece_along[ei] + t * np.hypot(*(other.end[ei] - other.start[ei]).T)
    heading = other.direction(li, at, tol.direction_m)
    cos_min = math.cos(math.radians(tol.heading_deg))
    ok = (at > 1e-6) & (at < other.length[li] - 1e-6) \
        & (np.abs(np.sum(heading * samples.direction[pi], 1)) >= cos_min)
    # Rivals: a line of the sample's own side, running the same way, much nearer to the foot
    # than the sample is (only a foot farther than rival_m from the sample can have one; a
    # road crossing there is no rival: it is the junction a moved road ends at).
    far = np.flatnonzero(ok & (d > tol.rival_m))
    ok[far] = d[far] <= own.nearest(foot[far], tol.match_m - tol.rival_m, heading[far],
                                    cos_min) + tol.rival_m
    pi, li, d, foot = pi[ok], li[ok], d[ok], foot[ok]
    order = np.lexsort((d, pi))
    first = np.ones(len(order), bool)
    first[1:] = pi[order][1:] != pi[order][:-1]
    chosen = order[first]
    best[pi[chosen]] = li[chosen]
    across = samples.direction[pi[chosen]]
    step = foot[chosen] - samples.xy[pi[chosen]]
    dist[pi[chosen]] = across[:, 0] * step[:, 1] - across[:, 1] * step[:, 0]
    feet[pi[chosen]] = foot[chosen]
    return best, dist, feet


def _lines(coords: Sequence[Coords]) -> np.ndarray:
    out = np.empty(len(coords), object)
    out[:] = [LineString(np.asarray(c, float)) for c in coords]
    return out


def _groups(owner: np.ndarray, count: int) -> list[np.ndarray]:
    """The sample indices of each of ``count`` lines (samples come grouped by line)."""
    bounds = np.searchsorted(owner, np.arange(count + 1))
    return [np.arange(bounds[i], bounds[i + 1]) for i in range(count)]


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of each run of True in ``flags``."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True))


def _join(end: np.ndarray, olds: np.ndarray, old_edges: _Edges, nodes: np.ndarray,
          near: int | None, reach: float, tol: Tolerances) -> tuple[np.ndarray | None, int | None]:
    """Where a new road's end meets the network: the nearest old node within
    :attr:`Tolerances.node_m` of its foot, else the foot on the nearest old segment (``near``
    when given: the one the line runs along next) within ``reach``; (None, None) if none."""
    point = shapely.points(end)
    if near is None:
        hit = old_edges.tree.query_nearest(point, max_distance=reach)
        if not len(hit):
            return None, None
        near = int(old_edges.piece_line[hit[0]])
    elif shapely.distance(olds[near], point) > reach:
        return None, None
    foot = shapely.get_coordinates(olds[near].interpolate(olds[near].project(point)))[0]
    gaps = np.hypot(*(nodes - foot).T) if len(nodes) else np.array([])
    if len(gaps) and gaps.min() <= tol.node_m:
        return nodes[int(gaps.argmin())], near
    return foot, near


def new_pieces(new: np.ndarray, samples: _Samples, seen_by: np.ndarray, olds: np.ndarray,
               old_edges: _Edges, tol: Tolerances) -> list[NewRoad]:
    """The stretches of new lines no old segment sees, at least :attr:`Tolerances.new_min_m`
    long. An end where the stretch runs on into a seen part is joined to the old segment seen
    there (its nearest node within :attr:`Tolerances.node_m`, else its side: the junction the
    new road makes); the line's own end is joined when within :attr:`Tolerances.join_m` of
    the network (a new road drawn to a T junction), else left free. Accepting the road then
    nodes it into the network there (a side joined splits the old segment in two)."""
    ends = shapely.get_coordinates(np.concatenate([shapely.get_point(olds, 0),
                                                   shapely.get_point(olds, -1)]))
    out: list[NewRoad] = []
    for line_index, mine in enumerate(_groups(samples.owner, len(new))):
        if not len(mine):
            continue
        line = new[line_index]
        length = line.length
        half = length / len(mine) / 2
        for first, last in _runs(seen_by[mine] < 0):
            start = 0.0 if first == 0 else samples.along[mine[first]] - half
            stop = length if last == len(mine) - 1 else samples.along[mine[last]] + half
            if stop - start < tol.new_min_m:
                continue
            coords = shapely.get_coordinates(substring(line, start, stop))
            joins: list[int | None] = []
            for at_end, index, neighbour in ((0, 0, first - 1), (-1, -1, last + 1)):
                own_end = neighbour < 0 or neighbour >= len(mine)
                near = None if own_end else int(seen_by[mine[neighbour]])
                reach = tol.join_m if own_end else tol.match_m + tol.step_m
                point, joined = _join(coords[index], olds, old_edges, ends, near, reach, tol)
                joins.append(joined)
                if point is not None:
                    coords = (np.vstack([point, coords]) if at_end == 0
                              else np.vstack([coords, point]))
            out.append(NewRoad(int(line_index), coords, (joins[0], joins[1])))
    return out


def match(old: Sequence[OldSegment], new: Sequence[Coords],
          coverage: Polygon | BaseGeometry | None = None,
          tol: Tolerances | None = None) -> Matching:
    """Match the re-survey's lines ``new`` against the network's segments ``old`` (all in one
    metric frame) inside ``coverage`` (None: everywhere the new data could be)."""
    tol = tol or Tolerances()
    olds, news = _lines([s.coords for s in old]), _lines(new)
    old_edges, new_edges = _Edges([s.coords for s in old]), _Edges(new)
    result = Matching()
    new_samples = _sample(new_edges, tol)
    if not len(olds):
        result.new = new_pieces(news, new_samples, np.full(len(new_samples.owner), -1), olds,
                                old_edges, tol)
        return result
    old_samples = _sample(old_edges, tol)
    if coverage is None:
        inside = np.ones(len(old_samples.owner), bool)
    else:
        shapely.prepare(coverage)
        inside = shapely.intersects_xy(coverage, old_samples.xy[:, 0], old_samples.xy[:, 1])
    sees, dist, feet = _seen(old_samples, old_edges, new_edges, tol)
    for segment, mine in zip(old, _groups(old_samples.owner, len(old)), strict=True):
        covered = mine[inside[mine]]
        if len(covered) * 2 < len(mine):
            result.unseen.append(segment.id)
            continue
        seen = covered[sees[covered] >= 0]
        share = len(seen) / len(covered)
        if share < tol.matched_share:
            result.missing.append(Missing(segment.id, round(share, 3), segment.edited))
            continue
        offset = abs(float(np.median(dist[seen])))
        if offset <= tol.moved_m:
            result.unchanged[segment.id] = round(offset, 3)
            continue
        own = np.asarray(segment.coords, float)
        course = shapely.get_coordinates(shapely.simplify(LineString(feet[seen]), 0.1)) \
            if len(seen) > 1 else feet[seen]
        result.moved.append(Moved(segment.id, round(offset, 3), round(share, 3),
                                  np.vstack([own[:1], course, own[-1:]]), segment.edited))
    if len(news):
        seen_by, _, _ = _seen(new_samples, new_edges, old_edges, tol)
        ids = [s.id for s in old]
        result.new = [NewRoad(r.line, r.coords, tuple(None if j is None else ids[j]
                                                       for j in r.joins))  # type: ignore[arg-type]
                      for r in new_pieces(news, new_samples, seen_by, olds, old_edges, tol)]
    return result
