"""Pieces of paint -> marking lines with a kind, a colour, a width and a confidence.

Thin pieces are chained end to end where the next one carries on the same line: the gap is
short enough for a dash pattern, and the chord across it turns from each end's direction by
about the same angle (what a line of constant curvature does; a dash of the neighbouring lane
is offset sideways, so its chord turns one way from one end and the other way from the other).
A chain with real gaps and little paint is ``dashed``; otherwise ``solid``, and a solid line
with asphalt on one side and something else (grass, kerb, verge) on the other is the
``road_edge``. Wide bars across the lines around them are ``stop_line``s; wide bars along
them (zebra stripes, hatching) and wide blobs (arrows) are ``other``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import shapely

from ingest.lanes.trace import Piece

Kind = str  # solid | dashed | stop_line | road_edge | other


@dataclass(frozen=True)
class ClassifyParams:
    """Thresholds in metres and degrees."""

    thick_m: float = 0.36
    """Pieces wider than this (and 2.5 pixels) are bars (stop lines, zebra) or symbols."""
    min_length_m: float = 0.5
    min_elongation: float = 3.0
    max_gap_m: float = 16.0
    """Longest gap between dashes that is joined."""
    max_turn_deg: float = 12.0
    """Largest angle between an end's direction and the chord across the gap."""
    max_asymmetry_deg: float = 8.0
    """Largest difference between the chord's turn from either end (constant curvature)."""
    short_gap_aside_m: float = 0.15
    """Across a gap shorter than ``dash_gap_m``, how far sideways the next piece may start."""
    dash_gap_m: float = 1.0
    """Gaps shorter than this are worn paint in a solid line, not a dash pattern."""
    dashed_paint_share: float = 0.6
    """A chain painted over less than this share of its length (gaps real) is dashed (dash
    patterns paint a third to a half; a worn or far, blurred solid line much more)."""
    longest_dash_m: float = 12.0
    """A chain with a piece longer than this is a broken solid line, not dashes."""
    lone_dash_m: float = 6.0
    """A single piece shorter than this is a dash of a line whose other dashes were not seen."""
    side_m: tuple[float, float] = (0.4, 1.2)
    """Band beside a line whose colour says road or not."""
    asphalt_saturation: float = 0.25
    """Road surface is grey: saturation below this (and not dark shadow, value above 0.15)."""
    on_road: float = 0.6
    """A marking needs this share of road surface beside it on at least one side."""
    off_road: float = 0.35
    """A solid line with less road surface than this on one side is the road's edge."""
    stop_angle_deg: float = 60.0
    """A bar this far from the direction of the lines near it crosses them: a stop line."""


@dataclass
class Marking:
    """One marking line in pixel coordinates (x = column, y = row)."""

    coords: np.ndarray
    kind: Kind
    colour: str
    width_m: float
    length_m: float
    confidence: float
    pieces: int = 1
    painted_share: float = 1.0
    members: list[Piece] = field(default_factory=list, repr=False)


def colour_of(hsv: np.ndarray) -> str:
    """``white``, ``yellow`` or ``unknown`` from paint pixels' HSV (H in degrees, S and V in
    [0, 1], as OpenCV gives for float input): the median, so edge pixels mixed with asphalt
    do not decide."""
    if len(hsv) == 0:
        return "unknown"
    h, s = float(np.median(hsv[:, 0])), float(np.median(hsv[:, 1]))
    if s < 0.22:
        return "white"
    if 25.0 <= h <= 70.0 and s >= 0.3:
        return "yellow"
    return "unknown"


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Signed angle from direction a to direction b, degrees."""
    return math.degrees(math.atan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1]))


def _link_cost(pa: np.ndarray, da: np.ndarray, pb: np.ndarray, db: np.ndarray, res: float,
               params: ClassifyParams) -> float | None:
    """Cost of continuing a line that leaves point ``pa`` heading ``da`` with one that starts
    at ``pb`` heading ``db``; None if they are not one line."""
    gap = pb - pa
    gap_px = float(np.hypot(*gap))
    if gap_px * res > params.max_gap_m:
        return None
    if gap_px * res < params.dash_gap_m:
        # A short gap (worn paint, a junction cut out): the chord is too short to measure
        # turns by; the two directions must agree and the ends line up sideways.
        turn = abs(_angle(da, db))
        aside = abs(float(da[0] * gap[1] - da[1] * gap[0])) * res
        ok = turn <= params.max_turn_deg and aside <= params.short_gap_aside_m
        return gap_px * res + turn / 10 if ok else None
    chord = gap / gap_px
    ta, tb = _angle(da, chord), _angle(chord, db)
    if max(abs(ta), abs(tb)) > params.max_turn_deg or abs(ta - tb) > params.max_asymmetry_deg:
        return None
    return gap_px * res + (abs(ta) + abs(tb)) / 10


def chain(thin: list[Piece], res: float, params: ClassifyParams) -> list[list[Piece]]:
    """Thin pieces joined end to end across gaps, greedily by cost, each piece once and each
    end linked at most once (a piece may be turned round to fit)."""
    n = len(thin)
    if not n:
        return []
    # End k < n is piece k's start, k >= n piece k - n's end; leaving a piece through its
    # start means travelling it backwards, and entering through an end the same.
    points = np.vstack([[p.coords[0] for p in thin], [p.coords[-1] for p in thin]])
    leaving = np.vstack([[-p.heads[0] for p in thin], [p.heads[1] for p in thin]])
    tree = shapely.STRtree(shapely.points(points))
    links = []
    for i in range(n):
        for side_i in (0, 1):
            k_out = i + side_i * n
            near = tree.query(shapely.Point(points[k_out]), predicate="dwithin",
                              distance=params.max_gap_m / res)
            for k in near:
                j, side_j = int(k) % n, int(k) // n
                if j == i:
                    continue
                cost = _link_cost(points[k_out], leaving[k_out], points[k], -leaving[k], res,
                                  params)
                if cost is not None:
                    links.append((cost, i, side_i, j, side_j))
    links.sort()
    used: set[tuple[int, int]] = set()
    parent = list(range(n))

    def root(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    neighbour: dict[tuple[int, int], tuple[int, int]] = {}
    for _, i, si, j, sj in links:
        if (i, si) in used or (j, sj) in used or root(i) == root(j):
            continue
        used.update({(i, si), (j, sj)})
        parent[root(i)] = root(j)
        neighbour[(i, si)] = (j, sj)
        neighbour[(j, sj)] = (i, si)
    chains, seen = [], set()
    for start in range(n):
        if start in seen:
            continue
        # Walk to one free end, then collect along the chain.
        i, side = start, 0
        guard = 0
        while (i, side) in neighbour and guard <= n:
            i, side = neighbour[(i, side)]
            side = 1 - side
            guard += 1
        out, enter = [], side  # enter i at `enter`: its other end leads on
        while True:
            seen.add(i)
            out.append(thin[i] if enter == 0 else thin[i].flipped())
            leave = 1 - enter
            if (i, leave) not in neighbour:
                break
            i, enter = neighbour[(i, leave)]
        chains.append(out)
    return chains


def side_means(coords: np.ndarray, fields: np.ndarray, res: float, band_m: tuple[float, float],
               step_m: float = 0.5) -> np.ndarray:
    """(2, k) mean of each of ``fields``' k layers in the band ``band_m`` from the line, on its
    left and on its right (NaN where the band leaves the image): what lies beside a line says
    whether it is on a road and whether it is the road's edge."""
    line = shapely.LineString(coords)
    along = np.arange(0.0, line.length + 1e-9, max(step_m / res, 1.0))
    at = shapely.get_coordinates(shapely.line_interpolate_point(line, along))
    ahead = shapely.get_coordinates(shapely.line_interpolate_point(line, along + 1.0))
    behind = shapely.get_coordinates(shapely.line_interpolate_point(line, along - 1.0))
    tangent = ahead - behind
    tangent /= np.maximum(np.hypot(tangent[:, 0], tangent[:, 1]), 1e-9)[:, None]
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])  # left of travel (y down)
    offsets = np.linspace(band_m[0], band_m[1], 3) / res
    rows, cols = fields.shape[:2]
    out = np.full((2, fields.shape[2]), np.nan)
    for k, sign in enumerate((1.0, -1.0)):
        xy = (at[:, None, :] + sign * offsets[None, :, None] * normal[:, None, :]).reshape(-1, 2)
        c, r = np.floor(xy[:, 0]).astype(int), np.floor(xy[:, 1]).astype(int)
        inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
        if inside.any():
            out[k] = fields[r[inside], c[inside]].mean(axis=0)
    return out


def _confidence(pieces: list[Piece], hat: np.ndarray, length_m: float) -> float:
    """Paint contrast (a top-hat of 80 is clear paint) times a length term (a short blob
    may be anything)."""
    contrast = float(np.median(np.concatenate([hat[p.rows, p.cols] for p in pieces])))
    return round(min(contrast / 80.0, 1.0) * (1 - math.exp(-length_m / 1.5)), 3)


def classify(all_pieces: list[Piece], hsv: np.ndarray, hat: np.ndarray, surface: np.ndarray,
             res: float, params: ClassifyParams = ClassifyParams()) -> list[Marking]:
    """Marking lines from the pieces of one image (``res`` metres per pixel; ``surface``:
    :func:`~ingest.lanes.paint.road_surface`)."""
    thick_px = max(params.thick_m / res, 2.5)
    thin: list[Piece] = []
    bars: list[Piece] = []
    for p in all_pieces:
        if p.length_px * res < params.min_length_m:
            continue
        if p.width_px > thick_px and p.length_px * res < params.lone_dash_m:
            bars.append(p)  # longer: a wide or blurred line (a far edge in an IPM mosaic)
        elif p.length_px >= params.min_elongation * p.width_px:
            thin.append(p)  # thin and short: a speck, a leaf, a marker disc
    surface = surface[..., None]
    out: list[Marking] = []
    for group in chain(thin, res, params):
        coords = np.vstack([p.coords for p in group])
        line = shapely.LineString(coords)
        length_m = line.length * res
        painted = sum(p.length_px for p in group) * res
        share = min(painted / max(length_m, 1e-9), 1.0)
        gaps = [float(np.hypot(*(b.coords[0] - a.coords[-1]))) * res
                for a, b in itertools.pairwise(group)]
        real_gaps = [g for g in gaps if g >= params.dash_gap_m]
        road = side_means(coords, surface, res, params.side_m)[:, 0]
        if not np.nanmax(road, initial=0.0) >= params.on_road:
            continue  # grass, trees, roofs: texture, not paint on a road
        dashes = max(p.length_px for p in group) * res <= params.longest_dash_m
        if (real_gaps and dashes and share < params.dashed_paint_share) or (
                len(group) == 1 and length_m < params.lone_dash_m):
            kind = "dashed"
        elif np.nanmin(road, initial=1.0) < params.off_road:
            kind = "road_edge"
        else:
            kind = "solid"
        rows = np.concatenate([p.rows for p in group])
        cols = np.concatenate([p.cols for p in group])
        width = _mean_width(group)
        out.append(Marking(coords, kind, colour_of(hsv[rows, cols]), round(width * res, 3),
                           round(length_m, 2), _confidence(group, hat, length_m), len(group),
                           round(share, 3), group))
    lines = [m for m in out if m.length_m >= 3.0]
    for group in chain(bars, res, params):  # a stop line cut where lane lines meet it
        coords = np.vstack([p.coords for p in group])
        if not np.nanmax(side_means(coords, surface, res, params.side_m)[:, 0],
                         initial=0.0) >= params.on_road:
            continue
        length_m = shapely.LineString(coords).length * res
        width = _mean_width(group)
        kind = "other"
        if length_m >= 1.5 and length_m >= params.min_elongation * width * res:
            kind = "stop_line" if _crosses(coords, lines, res, params) else "other"
        rows = np.concatenate([p.rows for p in group])
        cols = np.concatenate([p.cols for p in group])
        out.append(Marking(coords, kind, colour_of(hsv[rows, cols]), round(width * res, 3),
                           round(length_m, 2), _confidence(group, hat, length_m), len(group),
                           1.0, group))
    return out


def _mean_width(group: list[Piece]) -> float:
    """Length-weighted mean width of pieces (pixels)."""
    return sum(p.width_px * p.length_px for p in group) / sum(p.length_px for p in group)


def _crosses(bar: np.ndarray, lines: list[Marking], res: float, params: ClassifyParams) -> bool:
    """A bar crosses the road when the lines within 10 m of it run at least
    ``stop_angle_deg`` from its direction (none near: taken as a stop line)."""
    turn = turn_from_lines(direction_of(bar), shapely.LineString(bar), lines, res)
    return turn is None or turn >= params.stop_angle_deg


def direction_of(coords: np.ndarray) -> np.ndarray:
    """Unit direction from a line's first point to its last."""
    d = coords[-1] - coords[0]
    return d / max(float(np.hypot(*d)), 1e-9)


def axis_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two unit directions taken as undirected lines, degrees (0..90)."""
    return math.degrees(math.acos(min(abs(float(a @ b)), 1.0)))


def turn_from_lines(direction: np.ndarray, shape: shapely.LineString, lines: list[Marking],
                    res: float, near_m: float = 10.0) -> float | None:
    """Median angle (0..90 degrees) between ``direction`` and the lines within ``near_m`` of
    ``shape``, each where it passes nearest ``shape``'s middle; None when none is near: what
    tells a stop line (across the lines) and a zebra (along them) from other bars."""
    angles = []
    for m in lines:
        line = shapely.LineString(m.coords)
        if line.distance(shape) * res > near_m:
            continue
        at = line.project(shape.centroid)
        a, b = line.interpolate(max(at - 1.0 / res, 0)), line.interpolate(at + 1.0 / res)
        angles.append(axis_angle(direction, direction_of(np.array([[a.x, a.y], [b.x, b.y]]))))
    return float(np.median(angles)) if angles else None
