"""Pure geometry of a lane-level map, on flat numpy arrays in a metric frame.

Lines are stored flat: ``xy`` (V, 2) holds every vertex of every line, ``offsets`` (S + 1)
says where each line starts, the layout the routing graph and shapely's
``get_coordinates(return_index=True)`` use. Everything here is vectorised over all lines, so
a country-sized network costs seconds, not a Python loop per segment.

Lane bounds are the centreline moved sideways at every vertex along the *mitred* normal (the
bisector, lengthened by 1/cos of half the bend, capped at :data:`MITRE_LIMIT`). This keeps one
bound vertex per centreline vertex and never fails. It is an approximation: on a bend tighter
than the offset the inner bound folds into a small loop. GEOS's ``offset_curve`` removes such
folds but returns an empty line for a hairpin narrower than the road, and it costs one GEOS
call per bound, minutes for a million segments; a loop in a bound does not matter to routing.
"""

from __future__ import annotations

import math

import numpy as np
import shapely

MITRE_LIMIT = 3.0
"""Longest mitred normal, in offsets (a bend of more than ~140° is cut off there)."""
EPS_M = 1e-6


def standard_utm_zone(lon: float, lat: float) -> int:
    """The UTM zone GeographicLib's ``UTMUPS::StandardZone`` picks, which is what lanelet2's
    ``UtmProjector`` uses for its origin: the 6° zone, with the Norway (32V) and Svalbard
    (31X-37X) exceptions, so our local coordinates are the ones lanelet2 computes."""
    zone = min(60, math.floor((lon + 180.0) / 6.0) + 1)
    band = math.floor((lat + 80.0) / 8.0)
    if band == 17 and zone == 31 and lon >= 3.0:  # 56-64 N: southwest Norway is 32V
        zone = 32
    elif band >= 19 and 0.0 <= lon < 42.0:  # 72-84 N: Svalbard
        zone = 2 * math.floor((lon + 3.0) / 12.0) + 31
    return zone


def line_index(offsets: np.ndarray) -> np.ndarray:
    """The line each vertex of a flat array belongs to."""
    return np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))


def cumulative_lengths(xy: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Distance from its line's first vertex to each vertex."""
    step = np.hypot(*np.diff(xy, axis=0).T) if len(xy) else np.zeros(0)
    step[offsets[1:-1] - 1] = 0.0  # edges from one line to the next do not count
    total = np.concatenate([[0.0], np.cumsum(step)])
    return total - np.repeat(total[offsets[:-1]], np.diff(offsets))


def line_lengths(xy: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Length of each line."""
    return cumulative_lengths(xy, offsets)[offsets[1:] - 1]


def cut_lines(xy: np.ndarray, offsets: np.ndarray, start_m: np.ndarray, end_m: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """The part of each line from ``start_m`` after its start to ``end_m`` before its end
    (callers keep ``start_m + end_m`` below the length). Vertices closer than a micrometre to
    the one before are dropped, so every edge of the result has a direction.

    Vectorised because shapely's ``substring`` is one Python call per line."""
    n = len(offsets) - 1
    cum = cumulative_lengths(xy, offsets)
    which = line_index(offsets)
    length = cum[offsets[1:] - 1]
    lo, hi = start_m, length - end_m
    # A strictly increasing key over the whole array (1 m between lines) lets np.interp find
    # the edge of each cut point without a loop.
    key = cum + np.repeat(np.concatenate([[0.0], np.cumsum(length[:-1] + 1.0)]), np.diff(offsets))
    base = key[offsets[:-1]]

    def at(distance: np.ndarray) -> np.ndarray:
        return np.column_stack([np.interp(base + distance, key, xy[:, 0]),
                                np.interp(base + distance, key, xy[:, 1])])

    first, last = at(lo), at(hi)
    step = np.concatenate([[np.inf], np.diff(cum)])
    keep = (cum > lo[which] + EPS_M) & (cum < hi[which] - EPS_M) & (step > EPS_M)
    kept_per_line = np.bincount(which[keep], minlength=n)
    out_offsets = np.concatenate([[0], np.cumsum(kept_per_line + 2)])
    out = np.empty((out_offsets[-1], 2))
    out[out_offsets[:-1]] = first
    out[out_offsets[1:] - 1] = last
    kept_lines = which[keep]
    rank = np.arange(len(kept_lines)) - np.repeat(np.cumsum(kept_per_line) - kept_per_line,
                                                  kept_per_line)
    out[out_offsets[kept_lines] + 1 + rank] = xy[keep]
    return out, out_offsets


def left_normal(d: np.ndarray) -> np.ndarray:
    """Unit vectors turned 90° to the left (x east, y north)."""
    return np.column_stack([-d[:, 1], d[:, 0]])


def unit(v: np.ndarray) -> np.ndarray:
    """Row vectors scaled to length 1 (zero rows stay zero)."""
    norm = np.hypot(v[:, 0], v[:, 1])
    return v / np.where(norm > 0, norm, 1.0)[:, None]


def mitre(n_in: np.ndarray, n_out: np.ndarray) -> np.ndarray:
    """The mitred normal where an edge with left normal ``n_in`` meets one with ``n_out``:
    moving a vertex by ``offset * mitre`` keeps both edges' offsets exactly ``offset`` away."""
    m = n_in + n_out
    denom = 1.0 + np.einsum("ij,ij->i", n_in, n_out)
    m = m / np.maximum(denom, 1e-9)[:, None]
    norm = np.hypot(m[:, 0], m[:, 1])
    return m * np.minimum(1.0, MITRE_LIMIT / np.maximum(norm, 1e-12))[:, None]


def vertex_normals(xy: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Per vertex, the vector to move it by per metre of (leftward) offset: the edge's left
    normal at each end of a line, the mitred normal inside it."""
    edge_dir = unit(np.diff(xy, axis=0)) if len(xy) > 1 else np.zeros((0, 2))
    edge_n = left_normal(edge_dir)
    before = np.empty_like(xy)
    after = np.empty_like(xy)
    before[1:], after[:-1] = edge_n, edge_n
    starts, ends = offsets[:-1], offsets[1:] - 1
    before[starts] = after[starts]  # a line's first vertex has only the edge after it
    after[ends] = before[ends]
    return mitre(before, after)


def end_directions(xy: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit direction of each line's first and of its last edge, along the line."""
    starts, ends = offsets[:-1], offsets[1:] - 1
    return unit(xy[starts + 1] - xy[starts]), unit(xy[ends] - xy[ends - 1])


def signed_turn_deg(heading_in: np.ndarray, heading_out: np.ndarray) -> np.ndarray:
    """Turn angle from one heading to another, degrees, positive to the left."""
    cross = heading_in[:, 0] * heading_out[:, 1] - heading_in[:, 1] * heading_out[:, 0]
    dot = np.einsum("ij,ij->i", heading_in, heading_out)
    return np.degrees(np.arctan2(cross, dot))


def progressing(s: np.ndarray, group: np.ndarray, s_start: np.ndarray, s_end: np.ndarray
                ) -> np.ndarray:
    """Which inner points of polylines to keep so that each runs forwards: ``s`` is where
    each inner point projects along its line (``group``: which line, ascending), ``s_start``
    and ``s_end`` where the line's end points do. A point is kept when it lies beyond every
    point before it and before the end. This removes the small folds an offset grows on the
    inside of a tight bend (a bound running backwards there, which lanelet2's loader would
    read as the whole bound pointing the other way) and a curve's overshoot past its end."""
    if not len(s):
        return np.zeros(0, bool)
    span = float(max(np.abs(s).max(), np.abs(s_start).max(initial=0.0),
                     np.abs(s_end).max(initial=0.0))) * 2.0 + 1.0
    key = s + group * span
    running = np.maximum.accumulate(key)
    before = np.concatenate([[-np.inf], running[:-1]])
    first_of_group = np.concatenate([[True], group[1:] != group[:-1]])
    before[first_of_group] = -np.inf
    floor = np.maximum(before, s_start[group] + group * span)
    return (key > floor + EPS_M) & (s < s_end[group] - EPS_M)


def _signed_distance(line: np.ndarray, p: np.ndarray) -> float:
    """Distance from ``p`` to the polyline, positive on its left, as lanelet2's
    ``signedDistance`` decides the side: by the nearest segment (the first of equals), and
    where ``p`` projects onto that segment's end vertex, by the corner rule of its
    ``isLeftOf`` (the next segment decides when the two disagree and the corner turns
    towards ``p``'s side)."""
    a, b = line[:-1], line[1:]
    d = b - a
    length2 = np.einsum("ij,ij->i", d, d)
    t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.where(length2 > 0, length2, 1.0), 0, 1)
    gap = np.hypot(*(a + t[:, None] * d - p).T)
    i = int(np.argmin(gap))

    def left_of(q0: np.ndarray, q1: np.ndarray, q: np.ndarray) -> bool:
        return bool((q1[0] - q0[0]) * (q[1] - q0[1]) - (q1[1] - q0[1]) * (q[0] - q0[0]) > 0)

    left = left_of(a[i], b[i], p)
    if t[i] >= 1.0 and i + 1 < len(a):
        after = b[i + 1]
        if left != left_of(b[i], after, p) and left == left_of(a[i], b[i], after):
            left = not left
    return float(gap[i]) if left else -float(gap[i])


def _middle(line: np.ndarray) -> np.ndarray:
    return line[len(line) // 2] if len(line) > 2 else (line[0] + line[-1]) / 2


def bounds_oriented(left: np.ndarray, right: np.ndarray, margin: float = 0.01) -> bool:
    """Whether lanelet2's loader keeps these bounds as written (``geometry::align``: it turns
    the left bound round unless the right bound's middle point is on its right, then the right
    bound unless the left one's middle point is on its left), with ``margin`` metres to spare
    (the file's coordinates are rounded, and projected again by the loader)."""
    return (_signed_distance(left, _middle(right)) < -margin
            and _signed_distance(right, _middle(left)) > margin)


def turn_curves(p0: np.ndarray, t0: np.ndarray, p3: np.ndarray, t3: np.ndarray, samples: int
                ) -> np.ndarray:
    """Interior points (``samples`` per curve, shape (n, samples, 2)) of smooth curves from
    ``p0`` leaving along ``t0`` to ``p3`` arriving along ``t3``.

    Where the two tangent lines meet ahead of both ends (a turn), a quadratic Bézier curve
    with its control point there: it stays inside that triangle, so it never loops, however
    tight the turn (lanelet2 orients a bound by which side of it the other bound lies, so a
    looping bound would be read backwards). Elsewhere (straight on, an S-bend, a U-turn) a
    cubic one with handles a third of the chord long."""
    chord = p3 - p0
    cross = t0[:, 0] * t3[:, 1] - t0[:, 1] * t3[:, 0]
    safe = np.where(np.abs(cross) > 1e-6, cross, 1.0)
    a = (chord[:, 0] * t3[:, 1] - chord[:, 1] * t3[:, 0]) / safe  # p0 + a t0 = p3 - b t3
    b = (chord[:, 0] * t0[:, 1] - chord[:, 1] * t0[:, 0]) / safe
    length = np.hypot(*chord.T)
    meets = (np.abs(cross) > 1e-6) & (a > 0) & (b > 0) & (a < 3 * length) & (b < 3 * length)
    t = (np.arange(1, samples + 1) / (samples + 1))[None, :, None]
    apex = (p0 + a[:, None] * t0)[:, None, :]
    q0, q3 = p0[:, None, :], p3[:, None, :]
    quadratic = (1 - t) ** 2 * q0 + 2 * (1 - t) * t * apex + t**2 * q3
    h = (length / 3.0)[:, None]
    q1, q2 = (p0 + h * t0)[:, None, :], (p3 - h * t3)[:, None, :]
    cubic = (1 - t) ** 3 * q0 + 3 * (1 - t) ** 2 * t * q1 + 3 * (1 - t) * t**2 * q2 + t**3 * q3
    return np.where(meets[:, None, None], quadratic, cubic)


def lane_curves(left0: np.ndarray, right0: np.ndarray, t0: np.ndarray, left3: np.ndarray,
                right3: np.ndarray, t3: np.ndarray, samples: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """Inner points of the left and right bounds of lanes turning from the lane ends
    (``left0``, ``right0``) heading ``t0`` into the lanes starting at (``left3``, ``right3``)
    heading ``t3``: the lane centre follows :func:`turn_curves`, and the bounds lie half the
    lane width (changing evenly from one end's to the other's) either side of it. Both bounds'
    points then pair up across the lane (their middle points face each other), which is how
    lanelet2's loader tells the bounds' direction, even in a tight turn."""
    c0, c3 = (left0 + right0) / 2, (left3 + right3) / 2
    centre = turn_curves(c0, t0, c3, t3, samples)
    full = np.concatenate([c0[:, None], centre, c3[:, None]], axis=1)
    tangent = unit((full[:, 2:] - full[:, :-2]).reshape(-1, 2))
    normal = left_normal(tangent).reshape(centre.shape)
    t = (np.arange(1, samples + 1) / (samples + 1))[None, :, None]
    w0 = np.hypot(*(left0 - right0).T)[:, None, None]
    w3 = np.hypot(*(left3 - right3).T)[:, None, None]
    half = (w0 + (w3 - w0) * t) / 2
    return centre + half * normal, centre - half * normal


def straight_points(p0: np.ndarray, p3: np.ndarray, samples: int) -> np.ndarray:
    """``samples`` evenly spaced inner points of the straight lines from ``p0`` to ``p3``."""
    t = (np.arange(1, samples + 1) / (samples + 1))[None, :, None]
    return p0[:, None, :] + t * (p3 - p0)[:, None, :]


def spread_lanes(left0: np.ndarray, right0: np.ndarray, t0: np.ndarray, left3: np.ndarray,
                 right3: np.ndarray, t3: np.ndarray, samples: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Inner points of bounds drawn for lanes whose ends overlap (two roads meeting at a few
    degrees): straight from end to end, pushed apart sideways (up to a lane width each, most
    in the middle) across the mean heading, so each bound lies clearly on its own side of the
    other, which is all lanelet2's loader needs to keep the lanelet as written. The shape is
    a compromise (the lanelet bulges); the movement stays in the map."""
    heading = t0 + t3
    turned = np.hypot(*heading.T) < 0.2  # close to a U-turn: go across, from end to end
    c0, c3 = (left0 + right0) / 2, (left3 + right3) / 2
    heading[turned] = (c3 - c0)[turned]
    heading[np.hypot(*heading.T) < 1e-9] = t0[np.hypot(*heading.T) < 1e-9]
    normal = left_normal(unit(heading))[:, None, :]
    t = (np.arange(1, samples + 1) / (samples + 1))[None, :, None]
    width = np.maximum(np.hypot(*(left0 - right0).T), np.hypot(*(left3 - right3).T))
    push = width[:, None, None] * np.sin(np.pi * t)
    return (straight_points(left0, left3, samples) + push * normal,
            straight_points(right0, right3, samples) - push * normal)


def along_line(line: shapely.LineString, station: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """(point at each station of ``line``, unit direction of the line over the metre around
    it): a smooth local frame on a polyline, whose vertices' own directions jump."""
    def at(s: np.ndarray) -> np.ndarray:
        return shapely.get_coordinates(shapely.line_interpolate_point(line, s))

    t = at(np.minimum(station + 0.5, line.length)) - at(np.maximum(station - 0.5, 0.0))
    return at(station), t / np.maximum(np.hypot(t[:, 0], t[:, 1]), 1e-9)[:, None]


def station_offset(line: shapely.LineString, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(station along ``line``, signed offset from it, + left) of each point (metric)."""
    station = shapely.line_locate_point(line, shapely.points(xy))
    foot, t = along_line(line, station)
    d = xy - foot
    return station, d[:, 1] * t[:, 0] - d[:, 0] * t[:, 1]
