"""Lanelets from the paint: segments with stored lanes (``ugvmap ingest lanes``) cut into pieces
whose lanelets are bounded by the marking lines.

A painted segment is cut where its lane count changes (a range of ``segment_lanes``), where a
stop line crosses it, and where a boundary's line type changes (a dashed lane line turning
solid): a Lanelet2 bound has one type, and a lane change is allowed or not along a whole
lanelet. Cuts closer than :data:`MIN_PIECE_M` to a stronger one or to each other are
dropped (the line type of a piece is what most of its length is painted with). Each piece is
a road of its own for the layout (pieces of one range meet at joints, so lanelet2 sees one
lanelet follow the other) and each of its bounds carries the marking's vertices, its line
type (:func:`line_tags`) and the offset of the paint where the bound starts and ends, so the
layout places the end points on the paint. Stop lines become ``traffic_sign`` regulatory
elements of the lanes that end at them.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field, replace

import numpy as np
import shapely
import shapely.ops

from app.lanelet2.frame import Frame
from app.lanelet2.geometry import station_offset
from app.lanelet2.roads import (
    NetworkSelection,
    NodeTable,
    RoadTable,
    StoredBound,
    StoredLanes,
    concat,
)
from app.lanelet2.topology import lanes_fit

MIN_PIECE_M = 3.0
FIT_M = 0.75
"""How far from its range's boundary a stored bound may lie (``ingest lanes`` puts a line on
a boundary within the same distance)."""
THICK_M = 0.3
"""Painted lines at least this wide are ``line_thick``."""
GRID_M = 0.5
SIMPLIFY_M = 0.02

def line_tags(kind: str, colour: str, width_m: float | None, source: str) -> dict[str, str]:
    """Lanelet2's tags of a marking line: ``road_border`` for a road edge, else ``line_thin``
    (``line_thick`` when at least :data:`THICK_M` wide) with its ``subtype`` and ``color``
    where known; ``ugvmap:source=offset`` where no paint was found (a guess)."""
    if kind == "road_edge":
        tags = {"type": "road_border"}
    else:
        thick = width_m is not None and width_m >= THICK_M
        tags = {"type": "line_thick" if thick else "line_thin", "subtype": kind}
        if colour in ("white", "yellow"):
            tags["color"] = colour
    if source == "offset":
        tags["ugvmap:source"] = "offset"
    return tags


@dataclass
class PaintedSlot:
    """A bound of a piece drawn from the paint: the paint's vertices (map frame), where they
    lie along the piece's centreline and sideways of it, and the line's tags."""

    station: np.ndarray
    offset: np.ndarray
    xy: np.ndarray
    tags: dict[str, str]

    def offset_at(self, station: float) -> float:
        """The paint's offset at ``station`` (the nearest end's beyond the paint)."""
        return float(np.interp(station, self.station, self.offset))

    def inner(self, lo: float, hi: float) -> np.ndarray:
        """The paint's vertices strictly between stations ``lo`` and ``hi``, in order."""
        keep = (self.station > lo + 0.05) & (self.station < hi - 0.05)
        return self.xy[keep]


@dataclass
class StopLine:
    """A painted stop line: its end points (map frame), the arm whose entering lanes stop
    at it (arm ``2 p`` is piece ``p``'s start, ``2 p + 1`` its end) and whether those lanes
    lead to a node with a traffic light (whose element then governs them: no stop sign)."""

    xy: np.ndarray
    arm: int
    lit: bool = False


@dataclass
class Crossing:
    """A painted pedestrian crossing: the line across the road through its bars (map frame),
    how far it reaches along the road, and the row of the piece it crosses."""

    xy: np.ndarray
    width_m: float
    row: int


@dataclass
class Pieces:
    """What the layout needs of the painted pieces, by row of the (split) road table."""

    slots: dict[tuple[int, int], PaintedSlot] = field(default_factory=dict)
    """(row, slot k counted from the left edge along the geometry) -> its paint."""
    stops: list[StopLine] = field(default_factory=list)
    laterals: dict[int, np.ndarray] = field(default_factory=dict)
    """row -> each slot's offset left of the line (from the left edge) as its stored range
    says, for the slots no paint bounds: lanes as wide as stored, not evenly split."""
    crossings: list[Crossing] = field(default_factory=list)

    def painted_rows(self, n_rows: int) -> np.ndarray:
        """Which rows have any painted bound."""
        out = np.zeros(n_rows, bool)
        out[[row for row, _ in self.slots]] = True
        return out

    def take(self, rows: np.ndarray) -> Pieces:
        """The same pieces after the road table was reduced to ``rows`` (in that order)."""
        where = {int(r): i for i, r in enumerate(rows.tolist())}
        slots = {(where[r], k): s for (r, k), s in self.slots.items() if r in where}
        stops = [StopLine(s.xy, 2 * where[s.arm // 2] + s.arm % 2, s.lit) for s in self.stops
                 if s.arm // 2 in where]
        return Pieces(slots, stops, {where[r]: lat for r, lat in self.laterals.items()
                                     if r in where},
                      [replace(c, row=where[c.row]) for c in self.crossings if c.row in where])


@dataclass
class _Bound:
    """A stored bound in the map frame, along one segment's centreline."""

    row: StoredBound
    xy: np.ndarray
    station: np.ndarray
    offset: np.ndarray
    lo: float
    hi: float


def _cuts(length: float, strong: list[float], weak: list[float]) -> list[float]:
    """Piece ends: 0, the strong cuts, the weak ones at least :data:`MIN_PIECE_M` from any
    other kept cut, and the length."""
    kept = sorted({0.0, length, *[s for s in strong if MIN_PIECE_M <= s <= length - MIN_PIECE_M]})
    for s in sorted(weak):
        if min(abs(s - k) for k in kept) >= MIN_PIECE_M:
            kept = sorted([*kept, s])
    return kept


Piece = tuple[float, float, int, int, float, list[float]]
"""(from, to, forward, backward, road width, boundary offsets right to left) of a piece."""


def segment_pieces(centre: shapely.LineString, lanes: StoredLanes, frame: Frame
                   ) -> tuple[list[Piece], list[dict[int, PaintedSlot]],
                              list[tuple[np.ndarray, int, float]],
                              list[tuple[np.ndarray, int, float]]]:
    """Cut one painted segment (its metric centreline ``centre``): (pieces, per piece its
    painted slots by position from the right, stop lines as (end points, piece, offset),
    crossings as (end points, piece, reach along the road))."""
    length = centre.length
    scale = length / max(lanes.ranges[-1][1], 1e-9)
    ranges = [(lo * scale, hi * scale, f, b) for lo, hi, f, b in lanes.ranges]
    width = dict(zip(ranges, lanes.widths, strict=True))
    offsets = dict(zip(ranges, lanes.offsets, strict=True))
    bounds, stops, crossings = [], [], []
    for row in lanes.bounds:
        xy = frame.local(row.lonlat)
        if row.position is None:
            station, offset = station_offset(centre, xy)
            if row.kind == "stop_line":
                stops.append((xy[[0, -1]], float(np.median(station)), float(np.median(offset))))
            elif row.kind == "crosswalk" and row.width_m:
                crossings.append((xy[[0, -1]], float(np.median(station)), row.width_m))
            continue
        line = shapely.simplify(shapely.LineString(xy), SIMPLIFY_M)
        xy = shapely.get_coordinates(line)
        station, offset = station_offset(centre, xy)
        order = np.argsort(station, kind="stable")
        bounds.append(_Bound(row, xy[order], station[order], offset[order],
                             row.station_from_m * scale, row.station_to_m * scale))
    by_range = [[b for b in bounds if _fits(b, r, offsets[r])] for r in ranges]
    grid = np.arange(GRID_M / 2, length, GRID_M)
    owner = _owners(grid, ranges, by_range)
    keys = [_lane_change_key(cell) for cell in owner]
    change = [float(grid[i]) for i in range(1, len(grid)) if keys[i] != keys[i - 1]]
    cuts = _cuts(length, [hi for _, hi, _, _ in ranges[:-1]] + [s for _, s, _ in stops],
                 change)
    pieces, slots = [], []
    for lo, hi in itertools.pairwise(cuts):
        mid = (lo + hi) / 2
        i = next((j for j, x in enumerate(ranges) if x[0] <= mid <= x[1]), len(ranges) - 1)
        r = ranges[i]
        pieces.append((lo, hi, r[2], r[3], width[r], offsets[r]))
        inside = (grid >= lo) & (grid < hi)
        slots.append(_piece_slots(by_range[i], owner, inside, r, lo))
    ends = [(p[0], p[1]) for p in pieces]
    stop_lines = [(xy, int(np.argmin([abs(e[1 if offset < 0 else 0] - s) for e in ends])),
                   offset) for xy, s, offset in stops]
    crossed = [(xy, next(i for i, e in enumerate(ends) if s <= e[1] or i == len(ends) - 1),
                width) for xy, s, width in crossings]
    return pieces, slots, stop_lines, crossed


Cell = tuple[int, tuple["_Bound | None", ...]]


def _fits(b: _Bound, r: tuple[float, float, int, int], offsets: list[float]) -> bool:
    """Whether a stored bound is one of range ``r``'s: it runs along the range and lies
    where the range says its position's boundary is (within :data:`FIT_M`). Ranges read
    from the paint always fit their own bounds; ranges a person edited (``PUT .../lanes``)
    may no longer: a line of the old lanes is then not drawn as a bound of the new ones."""
    if b.row.position is None or b.row.position >= len(offsets) or not (
            b.hi > r[0] and b.lo < r[1]):
        return False
    # Where it lies along its length, not at its vertices: a simplified line has many on a
    # taper or a wobble and few on a straight run.
    lo, hi = max(r[0], float(b.station[0])), min(r[1], float(b.station[-1]))
    at = np.linspace(lo, hi, 50) if hi > lo else b.station
    offset = float(np.median(np.interp(at, b.station, b.offset)))
    return abs(offset - offsets[b.row.position]) <= FIT_M


def _owners(grid: np.ndarray, ranges: list[tuple[float, float, int, int]],
            by_range: list[list[_Bound]]) -> list[Cell]:
    """Per grid station, the range it lies in and the bound covering each of its positions."""
    out = []
    for s in grid.tolist():
        r = next((i for i, x in enumerate(ranges) if x[0] <= s <= x[1]), len(ranges) - 1)
        n = ranges[r][2] + ranges[r][3]
        out.append((r, tuple(_cover(by_range[r], k, s) for k in range(n + 1))))
    return out


def _lane_change_key(cell: Cell) -> tuple:
    """What a piece must not change along it: its range and each bound's type and subtype
    (colour and source may change; what lanelet2 allows across a bound may not)."""
    return (cell[0], *[None if b is None else (b.row.kind, _tags(b.row).get("type"))
                       for b in cell[1]])


def _cover(bounds: list[_Bound], position: int, s: float) -> _Bound | None:
    """The bound of ``position`` at station ``s`` (painted before guessed, then the more
    confident)."""
    at = [b for b in bounds if b.row.position == position and b.lo <= s <= b.hi]
    return max(at, key=lambda b: (b.row.source == "paint", b.row.confidence), default=None)


def _tags(row: StoredBound) -> dict[str, str]:
    return line_tags(row.kind, row.colour, row.width_m, row.source)


def _piece_slots(bounds: list[_Bound], owner: list[Cell], inside: np.ndarray,
                 r: tuple[float, float, int, int], lo: float) -> dict[int, PaintedSlot]:
    """The painted slots of one piece (stations relative to its start), by position, from
    the ``bounds`` of its range (:func:`_fits`); a slot's tags are those most of the piece's
    paint has (guessed ones where none is)."""
    out = {}
    cells = [owner[i] for i in np.flatnonzero(inside)]
    for k in range(r[2] + r[3] + 1):
        mine = [b for b in bounds if b.row.position == k]
        votes: dict[tuple[tuple[str, str], ...], tuple[int, int]] = {}
        for _, covers in cells:
            b = covers[k] if k < len(covers) else None
            if b is not None:
                key = tuple(sorted(_tags(b.row).items()))
                paint, total = votes.get(key, (0, 0))
                votes[key] = (paint + (b.row.source == "paint"), total + 1)
        if not mine or not votes:
            continue
        station = np.concatenate([b.station for b in mine])
        order = np.argsort(station, kind="stable")
        station = station[order]
        keep = np.concatenate([[True], np.diff(station) > 0.1])
        out[k] = PaintedSlot(station[keep] - lo,
                             np.concatenate([b.offset for b in mine])[order][keep],
                             np.concatenate([b.xy for b in mine])[order][keep],
                             dict(max(votes.items(), key=lambda kv: kv[1])[0]))
    return out


def split_painted(sel: NetworkSelection, frame: Frame) -> tuple[NetworkSelection, Pieces]:
    """The selection with every painted segment cut into its pieces (rows of the same
    segment id, joined by new nodes of negative ids), still ordered by segment id, and the
    pieces' paint by row. A segment whose paint does not fit its one-way rule (lanes against
    it, none in a direction it may be driven: :func:`~app.lanelet2.topology.lanes_fit`) is
    mapped as one without paint."""
    roads, nodes = sel.roads, sel.nodes
    has_paint = np.isin(roads.ids, np.fromiter(sel.paint, np.int64, len(sel.paint)))
    for row in np.flatnonzero(has_paint).tolist():
        ranges = sel.paint[int(roads.ids[row])].ranges
        has_paint[row] = all(lanes_fit(str(roads.oneway[row]), f, b) for _, _, f, b in ranges)
    if not has_paint.any():
        return sel, Pieces()
    rest, _ = roads.take(np.flatnonzero(~has_paint))
    tables = [rest]
    new_nodes: list[tuple[int, np.ndarray]] = []
    slots: list[dict[int, PaintedSlot]] = []
    laterals: list[np.ndarray] = []
    stops: list[tuple[np.ndarray, int, float, bool]] = []
    crossings: list[tuple[np.ndarray, int, float]] = []
    lit = dict(zip(nodes.ids.tolist(), nodes.traffic_light.tolist(), strict=True))
    for row in np.flatnonzero(has_paint).tolist():
        part, _ = roads.take(np.array([row]))
        xy = frame.local(part.lonlat)
        centre = shapely.LineString(xy)
        pieces, piece_slots, piece_stops, piece_crossings = segment_pieces(
            centre, sel.paint[int(part.ids[0])], frame)
        ends = [int(part.source[0])]
        for lo, *_ in pieces[1:]:
            new_nodes.append((-(len(new_nodes) + 1),
                              frame.lonlat(shapely.get_coordinates(centre.interpolate(lo)))[0]))
            ends.append(new_nodes[-1][0])
        ends.append(int(part.target[0]))
        base = sum(len(t) for t in tables) - len(rest)
        stops += [(xy_stop, base + p, offset,
                   lit.get(int(part.target[0] if offset < 0 else part.source[0]), False))
                  for xy_stop, p, offset in piece_stops]
        crossings += [(xy_cross, base + p, width) for xy_cross, p, width in piece_crossings]
        for i, (lo, hi, f, b, width, offsets) in enumerate(pieces):
            piece_xy = shapely.get_coordinates(shapely.ops.substring(centre, lo, hi))
            tables.append(RoadTable(
                ids=part.ids, source=np.array([ends[i]]), target=np.array([ends[i + 1]]),
                lonlat=frame.lonlat(piece_xy), offsets=np.array([0, len(piece_xy)]),
                length_m=np.array([hi - lo]), lanes_forward=np.array([f]),
                lanes_backward=np.array([b]), oneway=part.oneway,
                speed_limit_kph=part.speed_limit_kph, road_class=part.road_class,
                name=part.name, width_m=np.array([width])))
            slots.append({f + b - k: slot for k, slot in piece_slots[i].items()})
            laterals.append(np.array(offsets[::-1], np.float64))
    table = concat(tables)
    order = np.argsort(table.ids, kind="stable")
    split, _ = table.take(order)
    where = np.empty(len(order), np.int64)
    where[order] = np.arange(len(order))
    first = len(rest)
    painted = Pieces({(int(where[first + i]), k): slot for i, by_k in enumerate(slots)
                      for k, slot in by_k.items()},
                     [StopLine(xy, 2 * int(where[first + p]) + (1 if offset < 0 else 0), light)
                      for xy, p, offset, light in stops],
                     {int(where[first + i]): lat for i, lat in enumerate(laterals)},
                     [Crossing(xy, width, int(where[first + p])) for xy, p, width in crossings])
    ids = np.concatenate([nodes.ids, [i for i, _ in new_nodes]])
    lonlat = np.concatenate([nodes.lonlat, np.array([ll for _, ll in new_nodes]).reshape(-1, 2)])
    light = np.concatenate([nodes.traffic_light, np.zeros(len(new_nodes), bool)])
    node_order = np.argsort(ids, kind="stable")
    return replace(sel, roads=split, nodes=NodeTable(ids[node_order], lonlat[node_order],
                                                     light[node_order])), painted
