"""A segment's lanes and lane boundaries from the marking lines around it (metric coordinates).

The cuts of :func:`ingest.lanes.across.sections` along the segment say, station by station,
how many lanes each way the paint shows; runs of equal counts are the segment's lane ranges
(a run shorter than :data:`MIN_RANGE_M` is a missed dash or a blur, not a lane that opens,
and joins its neighbour). Within a range each boundary (its ``position`` from the right edge
along the segment's direction) lies at the median offset of the cuts that met them all; each
marking line near the segment is then cut into the stretches that follow one boundary of one
range, and stretches of a boundary no paint covers become ``offset`` boundaries (the range's
offset there, a guess that says it is one). Where a lane opens or ends along a painted taper
(the road edge, or the line beside the lane, running over from the old boundary to the new
one), the lane starts where the taper does and its boundary follows it (:func:`_tapered`).
Stop lines and crossings are kept whole, without a position.
Pure functions of shapely lines, tested without a database.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import shapely

from app.lanelet2.geometry import along_line, station_offset
from ingest.lanes.across import BOUNDING, Section, sections

MIN_RANGE_M = 6.0
"""Shortest run of cuts with one lane count kept as a range of its own."""
MAX_LANE_M = 4.5
"""A range with a lane wider than this and fewer lanes than a neighbour is that neighbour
with a line unseen (blurred or off the imagery), not a lane that ends."""
MATCH_M = 0.75
"""How far from a range's boundary a marking may lie and still be that boundary."""
MIN_STRETCH_M = 2.5
"""Shortest stretch of paint (or of missing paint) that makes a boundary row."""
MIN_KIND_M = 5.0
"""Shortest stretch whose kind differs from the rest of its boundary's (:func:`_main_kinds`)."""
SAMPLE_M = 0.25
ALONG = 0.7
"""A stretch must run along the segment: its stations span this share of its length (a
line crossing the segment at more than ~45° is not one of its boundaries)."""
REACH_M = 15.0
"""Marking lines further than this from the segment are not its road's."""
ACROSS = ("stop_line", "crosswalk")
"""Markings across the road, kept whole and without a position."""
TAPER_TOL_M = 0.25
"""A taper's line runs over from where it lies this close to the new boundary's offset."""
TAPER_SMOOTH_M = 2.0
"""A taper is looked for in its line's offsets averaged over this length..."""
TAPER_LEVEL = 0.02
"""...and ends where they change by less than this per metre."""
TAPER_MIN_M = 2.0
MAX_TAPER_M = 60.0
"""A line that runs over from one boundary to the next in less than :data:`TAPER_MIN_M` is
a lane that opens at once (the Lanelet2 map gives it its own short taper); one longer than
this, or steeper than 45 degrees, is not a taper."""


@dataclass(frozen=True)
class Paint:
    """A marking line in a metric frame (as :mod:`ingest.lanes.classify` measured it)."""

    line: shapely.LineString
    kind: str
    colour: str
    width_m: float
    confidence: float


@dataclass(frozen=True)
class LaneRange:
    """The segment's lanes between two stations: boundary offsets right to left (+ left of
    the segment), forward lanes first; ``confidence`` is the share of the range's cuts that
    met every boundary."""

    station_from_m: float
    station_to_m: float
    forward: int
    backward: int
    offsets: tuple[float, ...]
    confidence: float
    taper: tuple[int, tuple[tuple[float, float], ...]] | None = field(default=None,
                                                                      compare=False)
    """Where this range has a lane more than its neighbour and the paint widens into it:
    the new boundary's position and its painted (station, offset) pairs over the taper
    (found by :func:`_tapered`; boundary stretches follow it, it is not stored)."""

    @property
    def widths(self) -> list[float]:
        """Lane widths right to left."""
        return [round(float(w), 3) for w in np.diff(self.offsets)]

    def guessed_kind(self, position: int) -> str:
        """The kind of a boundary nothing was painted on: edge, the line between the
        directions, or a lane line."""
        if position in (0, len(self.offsets) - 1):
            return "road_edge"
        return "solid" if position == self.forward else "dashed"


@dataclass(frozen=True)
class Boundary:
    """One stretch of a marking (or of a guessed boundary) along the segment."""

    line: shapely.LineString
    kind: str
    colour: str
    width_m: float | None
    confidence: float
    position: int | None
    offset_m: float
    station_from_m: float
    station_to_m: float
    source: str  # paint / offset


def lane_ranges(reference: shapely.LineString, paint: list[Paint],
                step_m: float = 0.5) -> list[LaneRange]:
    """The segment's lane ranges, covering it from end to end (the first and last carry on
    to the segment's ends, where the imagery may stop short); [] when no cut met two
    boundaries."""
    cuts = sections(reference, [(p.line, p.kind) for p in paint], step_m=step_m,
                    reach_m=REACH_M)
    counts = []
    for cut in cuts:
        forward, backward = cut.lanes()
        counts.append((len(forward), len(backward)) if len(cut.offsets) >= 2 else (0, 0))
    ranges = [_range_of(cuts, cuts[start].station_m - step_m / 2,
                        cuts[stop - 1].station_m + step_m / 2, f, b)
              for start, stop, (f, b) in _runs(counts, step_m) if f + b]
    # Before the merge, so that a range whose lane a taper widens is not read as a line
    # unseen; after it too, where a short misread range between them hid the taper's range.
    if len(ranges) < 2:
        return _cover(ranges, reference.length)
    lines = [station_offset(reference, _samples(p.line)) for p in paint if p.kind in BOUNDING]
    ranges = _unseen_lines_merged(_tapered(lines, ranges, cuts))
    return _tapered(lines, _cover(ranges, reference.length), cuts)


def _range_of(cuts: list[Section], lo: float, hi: float, forward: int, backward: int
              ) -> LaneRange:
    """The range of ``forward`` + ``backward`` lanes from station ``lo`` to ``hi``: its
    boundaries at the median offsets of the cuts there that met them all."""
    inside = [c for c in cuts if lo <= c.station_m <= hi]
    full = [c for c in inside if len(c.offsets) == forward + backward + 1]
    offsets = np.median(np.array([c.offsets for c in full]), axis=0)
    return LaneRange(lo, hi, forward, backward, tuple(round(float(o), 3) for o in offsets),
                     round(len(full) / max(len(inside), 1), 3))


def _tapered(lines: list[tuple[np.ndarray, np.ndarray]], ranges: list[LaneRange],
             cuts: list[Section]) -> list[LaneRange]:
    """The ranges with each lane that opens (or ends) along a painted taper starting (or
    ending) where the taper does, and the taper kept on the range with more lanes.

    The cuts count a lane only once a line parts it from its neighbour: where the road edge
    widens over 20 m before the new lane's line is painted, the range with fewer lanes ran
    to the end of the taper and the new lane opened at once there; where the lane line starts
    with the taper, the widening edge was no boundary (too far from the new lane's offset)
    and the new lane was as wide as painted from its first metre. A taper is a stretch of one
    line whose offset runs steadily from the new boundary of the range with more lanes to
    a level nearer the other range's boundary beside it than halfway, over
    :data:`TAPER_MIN_M` to :data:`MAX_TAPER_M` (:func:`_taper`), leaving that level no
    further than 1 m into the range with more lanes. The range with fewer lanes is then
    measured again without the taper (its lane there up to twice as wide: with the taper
    much of it, the range read as a line unseen, :func:`_unseen_lines_merged`). ``lines``:
    each marking line's (stations, offsets) along the segment."""
    out = list(ranges)
    for i in range(len(out) - 1):
        a, b = out[i], out[i + 1]
        if abs(len(a.offsets) - len(b.offsets)) != 1:
            continue
        opening = len(b.offsets) > len(a.offsets)
        few, many = (a, b) if opening else (b, a)
        # The new boundary: the one without which the rest line up best with the other
        # range's (whose boundary beside a taper is pulled towards it).
        new = min(range(len(many.offsets)), key=lambda k: sum(
            abs(o - p) for o, p in zip(many.offsets[:k] + many.offsets[k + 1:], few.offsets,
                                       strict=True)))
        o_new = many.offsets[new]
        o_old = min(few.offsets, key=lambda p: abs(p - o_new))
        split = (a.station_to_m + b.station_from_m) / 2
        room = (few.station_to_m - few.station_from_m - MIN_RANGE_M,
                many.station_to_m - many.station_from_m - MIN_RANGE_M)
        for station, offset in lines:
            into_few = split - station if opening else station - split
            taper = _taper(into_few, offset, o_old, o_new, room)
            if taper is None:
                continue
            samples, leaves = taper
            t = split - leaves if opening else split + leaves
            pairs = sorted(zip(station[samples].round(3).tolist(),
                               offset[samples].round(3).tolist(), strict=True))
            many = replace(many, taper=(new, tuple(pairs)))
            lo, hi = (few.station_from_m, t) if opening else (t, few.station_to_m)
            few = _range_of(cuts, lo, hi, few.forward, few.backward) if any(
                lo <= c.station_m <= hi and len(c.offsets) == len(few.offsets) for c in cuts
            ) else replace(few, station_from_m=lo, station_to_m=hi)
            many = replace(many, station_from_m=t) if opening else \
                replace(many, station_to_m=t)
            out[i], out[i + 1] = (few, many) if opening else (many, few)
            break
    return out


def _taper(into_few: np.ndarray, offset: np.ndarray, o_old: float, o_new: float,
           room: tuple[float, float]) -> tuple[np.ndarray, float] | None:
    """A line's taper from ``o_new`` to about ``o_old``, ``into_few`` being each sample's
    metres from the split into the range with fewer lanes: (its samples, in that order, and
    where it leaves the old boundary), or None. ``room``: how far the split may move into
    either range and leave it a range.

    Extracted paint wobbles by a few centimetres, as much as a long taper moves between two
    samples, so the offsets are smoothed over :data:`TAPER_SMOOTH_M` first. The old
    boundary's level is the line's own where it stops running over (the range's median
    offset is pulled towards the taper when the taper is much of the range), and the taper's
    ends are where a line fitted to its middle (a fifth to four fifths of the way across)
    meets the two levels, not where the paint first comes near them."""
    order = np.argsort(into_few, kind="stable")
    u, d = into_few[order], offset[order]
    half = max(int(TAPER_SMOOTH_M / SAMPLE_M / 2), 1)
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    smooth = np.convolve(np.pad(d, half, mode="edge"), kernel, mode="valid")
    step = 2 * half  # the slope over the smoothing length, not between two samples
    slope_ahead = np.zeros(len(u))
    slope_ahead[:-step] = (smooth[step:] - smooth[:-step]) / np.maximum(u[step:] - u[:-step],
                                                                         1e-9)
    towards = np.sign(o_old - o_new)
    at_new = np.flatnonzero(np.abs(smooth - o_new) <= TAPER_TOL_M)
    # The last sample at the new boundary before the line runs over, then the first one
    # past halfway from which the line runs level again.
    leaving = at_new[(np.append(np.diff(at_new), 2) > 1) & (at_new < len(u) - step)]
    for lo in leaving.tolist():
        level = np.flatnonzero((np.abs(slope_ahead) < TAPER_LEVEL) & (np.arange(len(u)) > lo)
                               & ((smooth - o_new) * towards > abs(o_old - o_new) / 2))
        if not len(level) or level[0] >= len(u) - step:
            continue
        hi = int(level[0])
        o_level = float(np.median(smooth[hi:hi + step + 1]))
        if abs(o_level - o_old) > abs(o_new - o_old) / 2 or not np.all(
                np.diff(smooth[lo:hi + 1]) * towards >= -0.02):
            continue
        across = (d[lo:hi + 1] - o_new) / (o_level - o_new)
        middle = (across > 0.2) & (across < 0.8)
        if middle.sum() < 3:
            continue
        slope, at = np.polyfit(u[lo:hi + 1][middle], d[lo:hi + 1][middle], 1)
        if slope * towards <= 0:
            continue
        leaves, reaches = (o_level - at) / slope, (o_new - at) / slope
        length = leaves - reaches
        if (TAPER_MIN_M <= length <= MAX_TAPER_M and abs(o_new - o_level) <= length
                and -1.0 < leaves <= room[0] and reaches >= -room[1]):
            return order[(u >= reaches) & (u <= leaves)], float(leaves)
    return None


def _unseen_lines_merged(ranges: list[LaneRange]) -> list[LaneRange]:
    """Ranges that are a longer neighbour seen wrongly dropped (the neighbour's lanes stretch
    over them, :func:`_cover`). Two ranges of different lane counts are a lane that opens or
    ends only when every line of the one with fewer goes on in the other where it was
    (within :data:`MATCH_M`) and no lane of it is wider than :data:`MAX_LANE_M`; otherwise the
    shorter of the two is a line unseen (blurred, off the imagery), a line that is not one
    (paint of the next road), or the segment straying off the road there (an extracted
    centreline's end curling across it)."""
    def length(r: LaneRange) -> float:
        return r.station_to_m - r.station_from_m

    def wrong(i: int) -> bool:
        r = ranges[i]
        for j in (i - 1, i + 1):
            if not 0 <= j < len(ranges) or length(ranges[j]) <= length(r):
                continue
            fewer, more = sorted((r, ranges[j]), key=lambda x: x.forward + x.backward)
            carried_on = all(min(abs(o - p) for p in more.offsets) <= MATCH_M
                             for o in fewer.offsets)
            if not carried_on or max(fewer.widths) > MAX_LANE_M:
                return True
        return False

    while True:
        bad = [i for i in range(len(ranges)) if wrong(i)]
        if not bad:
            return ranges
        ranges = [r for i, r in enumerate(ranges) if i != bad[0]]


def _runs(counts: list[tuple[int, int]], step_m: float
          ) -> list[tuple[int, int, tuple[int, int]]]:
    """(start, stop, count) runs of equal counts, the shortest under :data:`MIN_RANGE_M`
    merged into its longer neighbour until none is left (or one run)."""
    runs: list[tuple[int, int, tuple[int, int]]] = []
    for i, c in enumerate(counts):
        if runs and runs[-1][2] == c:
            runs[-1] = (runs[-1][0], i + 1, c)
        else:
            runs.append((i, i + 1, c))
    while len(runs) > 1:
        i = min(range(len(runs)), key=lambda j: runs[j][1] - runs[j][0])
        if (runs[i][1] - runs[i][0]) * step_m >= MIN_RANGE_M:
            break
        left = runs[i - 1] if i > 0 else None
        right = runs[i + 1] if i + 1 < len(runs) else None
        into = left if right is None or (left is not None and
                                         left[1] - left[0] >= right[1] - right[0]) else right
        assert into is not None
        merged = (min(into[0], runs[i][0]), max(into[1], runs[i][1]), into[2])
        lo = i - 1 if into is left else i
        runs[lo:lo + 2] = [merged]
        if lo > 0 and runs[lo - 1][2] == merged[2]:
            runs[lo - 1:lo + 1] = [(runs[lo - 1][0], merged[1], merged[2])]
        if lo + 1 < len(runs) and runs[lo + 1][2] == runs[lo][2]:
            runs[lo:lo + 2] = [(runs[lo][0], runs[lo + 1][1], runs[lo][2])]
    return runs


def _cover(ranges: list[LaneRange], length: float) -> list[LaneRange]:
    """The ranges stretched to meet halfway across the gaps between them and to reach both
    ends of the segment."""
    out = []
    for i, r in enumerate(ranges):
        lo = 0.0 if i == 0 else (ranges[i - 1].station_to_m + r.station_from_m) / 2
        hi = length if i == len(ranges) - 1 else (r.station_to_m + ranges[i + 1].station_from_m) / 2
        out.append(replace(r, station_from_m=round(lo, 3), station_to_m=round(hi, 3)))
    return out


def _samples(line: shapely.LineString) -> np.ndarray:
    at = np.append(np.arange(0.0, line.length, SAMPLE_M), line.length)
    return shapely.get_coordinates(shapely.line_interpolate_point(line, at))


def boundaries(reference: shapely.LineString, paint: list[Paint], ranges: list[LaneRange],
               elsewhere: shapely.Geometry | None = None) -> list[Boundary]:
    """The segment's boundaries: each marking's stretches that follow one boundary of one
    range (or stop lines, whole), then ``offset`` rows where a boundary has no paint.
    ``elsewhere``: the other segments near this one; paint nearer to them is theirs."""
    out: list[Boundary] = []
    length = reference.length
    starts = np.array([r.station_from_m for r in ranges])
    for p in paint:
        xy = _samples(p.line)
        station, offset = station_offset(reference, xy)
        mine = (station > 0) & (station < length) & (np.abs(offset) <= REACH_M)
        if elsewhere is not None and not elsewhere.is_empty:
            mine &= shapely.distance(shapely.points(xy), reference) <= \
                shapely.distance(shapely.points(xy), elsewhere)
        if p.kind in ACROSS:
            if mine.sum() >= 2:
                out.append(Boundary(shapely.LineString(xy[mine]), p.kind, p.colour, p.width_m,
                                    p.confidence, None, round(float(np.median(offset[mine])), 3),
                                    round(float(station[mine].min()), 3),
                                    round(float(station[mine].max()), 3), "paint"))
            continue
        if p.kind not in BOUNDING or not ranges:
            continue
        label = np.full(len(xy), -1)
        which = np.clip(np.searchsorted(starts, station, side="right") - 1, 0, len(ranges) - 1)
        for i in np.flatnonzero(mine):
            offs = _offsets_at(ranges[which[i]], float(station[i]))
            k = int(np.argmin(np.abs(offs - offset[i])))
            if abs(offs[k] - offset[i]) <= MATCH_M:
                label[i] = which[i] * 64 + k
        edges = np.flatnonzero(np.diff(label)) + 1
        for run in np.split(np.arange(len(xy)), edges):
            if label[run[0]] < 0 or len(run) < 2:
                continue
            s = station[run]
            if s.max() - s.min() < max(MIN_STRETCH_M, ALONG * SAMPLE_M * (len(run) - 1)):
                continue  # short, or crossing the segment (where it leaves the road)
            out.append(Boundary(shapely.LineString(xy[run]), p.kind, p.colour, p.width_m,
                                p.confidence, int(label[run[0]] % 64),
                                round(float(np.median(offset[run])), 3),
                                round(float(s.min()), 3), round(float(s.max()), 3), "paint"))
    return (kept := _main_kinds(out, starts)) + _guessed(reference, ranges, kept)


def _offsets_at(r: LaneRange, station: float) -> np.ndarray:
    """The range's boundary offsets at ``station``: its taper's painted offset where the
    station lies along the taper."""
    offs = np.array(r.offsets)
    if r.taper is not None:
        k, pairs = r.taper
        along, across = np.array(pairs).T
        if along[0] <= station <= along[-1]:
            offs[k] = np.interp(station, along, across)
    return offs


def _main_kinds(found: list[Boundary], starts: np.ndarray) -> list[Boundary]:
    """The stretches with their boundary's main kind (the most painted length of that
    position in that range), and those of another kind at least :data:`MIN_KIND_M` long (a
    dashed line turning solid before a junction); a short one of another kind is paint of a
    neighbouring line where the segment strays (an ``offset`` boundary goes there)."""
    def boundary(b: Boundary) -> tuple[int, int | None]:
        middle = (b.station_from_m + b.station_to_m) / 2
        return int(np.searchsorted(starts, middle, side="right")), b.position

    length: dict[tuple[int, int | None], dict[str, float]] = {}
    for b in found:
        kinds = length.setdefault(boundary(b), {})
        kinds[b.kind] = kinds.get(b.kind, 0.0) + b.station_to_m - b.station_from_m
    return [b for b in found if b.position is None
            or b.kind == max(length[boundary(b)].items(), key=lambda kv: kv[1])[0]
            or b.station_to_m - b.station_from_m >= MIN_KIND_M]


def _guessed(reference: shapely.LineString, ranges: list[LaneRange],
             found: list[Boundary]) -> list[Boundary]:
    """``offset`` boundaries over each stretch of a range's boundary no paint covers."""
    out = []
    for r in ranges:
        for k, offset in enumerate(r.offsets):
            covered = sorted((b.station_from_m, b.station_to_m) for b in found
                             if b.position == k and b.station_to_m > r.station_from_m
                             and b.station_from_m < r.station_to_m)
            at = r.station_from_m
            for lo, hi in [*covered, (r.station_to_m, r.station_to_m)]:
                if lo - at >= MIN_STRETCH_M:
                    out.append(_offset_line(reference, r, k, offset, at, lo))
                at = max(at, hi)
    return out


def _offset_line(reference: shapely.LineString, r: LaneRange, k: int, offset: float,
                 lo: float, hi: float) -> Boundary:
    stations = np.append(np.arange(lo, hi, 1.0), hi)
    centre, t = along_line(reference, stations)
    xy = centre + offset * np.column_stack([-t[:, 1], t[:, 0]])
    return Boundary(shapely.LineString(xy), r.guessed_kind(k), "unknown", None, 0.0, k,
                    offset, round(float(lo), 3), round(float(hi), 3), "offset")
