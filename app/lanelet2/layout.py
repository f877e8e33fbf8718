"""Where every lane of the map goes: lanes per direction, widths, which nodes are joints or
junctions and how far roads stop short of them, the cut centrelines and their offset
normals, and every bound's end point (shared at joints) with its id.

Lanes are centred on the segment's line, lane width apart, backward lanes on the left of the
digitising direction and forward lanes on the right (right-hand traffic). A segment's
bounds are its *slots*: boundary ``k`` (0 = the left edge along the geometry) of segment
``s`` is slot ``slot_offsets[s] + k``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from app.lanelet2 import topology as topo
from app.lanelet2.frame import Frame, IdSource
from app.lanelet2.geometry import (
    cut_lines,
    end_directions,
    left_normal,
    line_index,
    line_lengths,
    mitre,
    unit,
    vertex_normals,
)
from app.lanelet2.paint import Pieces, split_painted
from app.lanelet2.priority import Priority, plan_priorities
from app.lanelet2.roads import NetworkSelection, RoadTable
from app.routing.costs import effective_speed_kph

JOINT_PASSES = 3
MIN_CHORD_M = 0.01
AWAY_SAMPLE_M = 5.0
STRAIGHT_BELOW_WIDTHS = 2.0  # a folded line shorter than twice its road's width


def _subset(roads: RoadTable, rows: np.ndarray, xy: np.ndarray
            ) -> tuple[RoadTable, np.ndarray]:
    """The rows ``rows`` of ``roads`` and of its map-frame vertices ``xy``."""
    table, gather = roads.take(rows)
    return table, xy[gather]


@dataclass
class Layout:
    """Everything the writing passes need, arrays over the mapped segments."""

    roads: RoadTable
    node_ids: np.ndarray
    traffic_light: np.ndarray
    forward: np.ndarray
    backward: np.ndarray
    width: np.ndarray
    speed: np.ndarray
    arms: topo.Arms
    xy: np.ndarray  # cut centrelines, map frame
    offsets: np.ndarray
    normals: np.ndarray
    straight: np.ndarray  # (S) lines written with straight bounds
    away: np.ndarray  # (2S, 2) unit direction of each arm away from its node
    slot_offsets: np.ndarray  # (S + 1): boundary k of segment s is slot slot_offsets[s] + k
    end_ids: np.ndarray  # (2, slots): point id of each boundary at the start / end
    end_xy: np.ndarray  # (2, slots, 2)
    re_ids: np.ndarray  # (2S) traffic-light element of the lanes entering at the arm, or 0
    defects: list[topo.Defect]
    pieces: Pieces  # the bounds drawn from the paint, by (row, slot)
    cut: np.ndarray  # (2, S) stations where each line's lanelets start and end
    stop_ids: dict[int, int]  # arm -> the stop line element of the lanes entering there
    priorities: list[Priority]  # right-of-way elements at junctions, from the stop lines
    tapers: list[tuple[int, int, float]]  # (slot, end, offset): a lane opening or ending


def plan_layout(sel: NetworkSelection, frame: Frame, ids: IdSource) -> Layout:
    """Decide lanes, nodes and cuts; place every bound's end point and give it an id.
    Painted segments are cut into pieces first (:func:`app.lanelet2.paint.split_painted`)."""
    sel, pieces = split_painted(sel, frame)
    roads, nodes = sel.roads, sel.nodes
    n_nodes = len(nodes.ids)
    src = np.searchsorted(nodes.ids, roads.source)
    dst = np.searchsorted(nodes.ids, roads.target)
    xy = frame.local(roads.lonlat)
    length = line_lengths(xy, roads.offsets)
    keep, rep, defects = topo.contract_zero_length(roads, length, src, dst, n_nodes)
    src, dst = rep[src], rep[dst]
    defects += topo.loops(roads, src, dst, keep)
    rows = np.flatnonzero(keep)
    kept, kept_xy = _subset(roads, rows, xy)
    lines = shapely.linestrings(kept_xy, indices=line_index(kept.offsets))
    drop, dups = topo.duplicates(kept.ids, np.asarray(lines), src[rows], dst[rows])
    defects += dups
    rows = rows[~drop]
    pieces = pieces.take(rows)
    painted = pieces.painted_rows(len(rows))
    table, xy = _subset(roads, rows, xy)
    src, dst, length = src[rows], dst[rows], length[rows]
    forward, backward, lane_defects = topo.effective_lanes(table)
    defects += lane_defects
    n = forward + backward
    width = topo.lane_widths(table, n)
    slot_offsets = np.concatenate([[0], np.cumsum(n + 1)])
    away = _away(xy, table.offsets, length)
    # A joint whose shared points would fold a bound becomes a junction (cut back, joined by
    # a connecting lanelet); that changes the cuts of its roads, hence a few passes.
    demoted = np.zeros(n_nodes, bool)
    opening = nodes.ids < 0  # where split_painted cut a segment: its lane count may change
    for _ in range(JOINT_PASSES):
        arms = topo.arms(src, dst, forward, backward, width, length, away, n_nodes, demoted,
                         opening)
        geo = _place(arms, xy, table.offsets, n, width, slot_offsets, pieces, painted)
        bad = _folded(geo.xy, geo.offsets, geo.normals, geo.end_xy, slot_offsets, n, width,
                      geo.straight) & ~painted
        bad_joints = np.concatenate([arms.node[(arms.partner >= 0) & np.repeat(bad, 2)],
                                     geo.unmatched])
        if not len(bad_joints):
            break
        demoted[bad_joints] = True
    end_ids = ids.take(geo.end_xy.shape[1] * 2).reshape(2, -1)
    end_ids[geo.joined_b] = end_ids[geo.joined_a]
    traffic_light = np.zeros(n_nodes, bool)  # a merged node keeps the light of any part
    np.logical_or.at(traffic_light, rep, nodes.traffic_light)
    lit = traffic_light[arms.node] & (arms.lanes_in > 0)
    re_ids = np.zeros(len(arms.node), np.int64)
    re_ids[lit] = ids.take(int(lit.sum()))
    speed = effective_speed_kph(table.speed_limit_kph, table.road_class)
    away = np.column_stack([geo.first_dir, -geo.last_dir]).reshape(-1, 2)  # where cut
    stops = {stop.arm: int(ids.take(1)[0]) for stop in pieces.stops if not stop.lit}
    priorities = plan_priorities(arms, traffic_light, painted, sorted(stops), length, ids)
    return Layout(table, nodes.ids, traffic_light, forward, backward, width, speed, arms,
                 geo.xy, geo.offsets, geo.normals, geo.straight, away, slot_offsets, end_ids,
                 geo.end_xy, re_ids, defects, pieces, geo.cut, stops, priorities, geo.tapers)


def _away(xy: np.ndarray, offsets: np.ndarray, length: np.ndarray) -> np.ndarray:
    """(2S, 2) unit direction in which each arm leaves its node: towards the point
    :data:`AWAY_SAMPLE_M` along it (a curving road's first edge can point elsewhere)."""
    lines = shapely.linestrings(xy, indices=line_index(offsets))
    reach = np.minimum(AWAY_SAMPLE_M, length / 2)
    start = shapely.get_coordinates(shapely.line_interpolate_point(lines, reach))
    end = shapely.get_coordinates(shapely.line_interpolate_point(lines, length - reach))
    first, last = xy[offsets[:-1]], xy[offsets[1:] - 1]
    return unit(np.column_stack([start - first, end - last]).reshape(-1, 2))


@dataclass
class _Placed:
    """Cut centrelines, their offset normals and every bound's end points."""

    xy: np.ndarray
    offsets: np.ndarray
    normals: np.ndarray
    first_dir: np.ndarray
    last_dir: np.ndarray
    end_xy: np.ndarray  # (2, slots, 2)
    straight: np.ndarray  # (S) lines whose bounds are straight (no inner vertices)
    joined_a: tuple[np.ndarray, np.ndarray]  # (end, slot) of joint points, first arm
    joined_b: tuple[np.ndarray, np.ndarray]  # the same points at the second arm
    cut: np.ndarray  # (2, S) stations along the uncut lines where the cut ones start and end
    unmatched: np.ndarray  # openings whose lanes could not be matched (to be junctions)
    tapers: list[tuple[int, int, float]]  # (slot, end, offset) of bounds an opening pulls in


def _laterals(n: np.ndarray, width: np.ndarray, slot_offsets: np.ndarray, pieces: Pieces,
              cut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(2, slots) twice: how far left of its line each bound starts and ends: lanes side by
    side centred on the line, as the stored range places them where it has lanes, or where
    the paint is at the cut stations; and the same as the ranges alone place them."""
    seg = np.repeat(np.arange(len(n)), n + 1)
    k = np.arange(slot_offsets[-1]) - slot_offsets[seg]
    stored = np.tile((n[seg] / 2.0 - k) * width[seg], (2, 1))
    for s, lateral in pieces.laterals.items():
        if len(lateral) == n[s] + 1:
            stored[:, slot_offsets[s]:slot_offsets[s + 1]] = lateral
    out = stored.copy()
    for (s, slot_k), slot in pieces.slots.items():
        out[0, slot_offsets[s] + slot_k] = slot.offset_at(float(cut[0, s]))
        out[1, slot_offsets[s] + slot_k] = slot.offset_at(float(cut[1, s]))
    return out, stored


def _place(arms: topo.Arms, xy: np.ndarray, offsets: np.ndarray, n: np.ndarray,
           width: np.ndarray, slot_offsets: np.ndarray, pieces: Pieces, painted: np.ndarray
           ) -> _Placed:
    """Cut the centrelines at the junctions and place the bounds' end points.

    A short line around a sharp bend would fold its inner bound back (the offset of a bend
    tighter than the offset runs backwards), and lanelet2's loader, which orients each bound
    by the side the other bound's middle point is on, may then turn one bound round: such
    lines get straight bounds, parallel to their chord (painted ones keep their paint)."""
    cxy, coff = cut_lines(xy, offsets, arms.cut_m[0::2], arms.cut_m[1::2])
    cut = np.stack([arms.cut_m[0::2], line_lengths(xy, offsets) - arms.cut_m[1::2]])
    lateral, stored = _laterals(n, width, slot_offsets, pieces, cut)
    normals = vertex_normals(cxy, coff)
    first_dir, last_dir = end_directions(cxy, coff)
    seg = np.repeat(np.arange(len(n)), n + 1)
    first_v, last_v = coff[:-1][seg], coff[1:][seg] - 1

    def ends() -> np.ndarray:
        return np.stack([cxy[first_v] + lateral[0][:, None] * normals[first_v],
                         cxy[last_v] + lateral[1][:, None] * normals[last_v]])

    end_xy = ends()
    _join(arms, n, lateral, cxy, coff, first_dir, last_dir, slot_offsets, end_xy)
    straight = np.zeros(len(n), bool)
    chord = cxy[coff[1:] - 1] - cxy[coff[:-1]]
    chord_m = np.hypot(*chord.T)
    folded = _folded(cxy, coff, normals, end_xy, slot_offsets, n, width, straight)
    straight = folded & ~painted & (chord_m > MIN_CHORD_M) & (
        line_lengths(cxy, coff) < STRAIGHT_BELOW_WIDTHS * np.maximum(n, 1) * width)
    vertex_line = line_index(coff)
    at = straight[vertex_line]
    normals[at] = left_normal(unit(chord))[vertex_line[at]]
    end_xy = ends()
    joined_a, joined_b = _join(arms, n, lateral, cxy, coff, first_dir, last_dir, slot_offsets,
                               end_xy)
    # A painted bound that lies off its range's offset at its end runs over to it from
    # there: the paint's own taper of a lane that opens (or ends).
    opened_a, opened_b, unmatched, tapers = _open(arms, lateral, cxy, coff, first_dir, last_dir,
                                                  slot_offsets, end_xy,
                                                  np.abs(lateral - stored) > OPEN_MATCH_M)
    joined_a = (np.concatenate([joined_a[0], opened_a[0]]),
                np.concatenate([joined_a[1], opened_a[1]]))
    joined_b = (np.concatenate([joined_b[0], opened_b[0]]),
                np.concatenate([joined_b[1], opened_b[1]]))
    return _Placed(cxy, coff, normals, first_dir, last_dir, end_xy, straight, joined_a,
                   joined_b, cut, unmatched, tapers)


def _folded(cxy: np.ndarray, coff: np.ndarray, normals: np.ndarray, end_xy: np.ndarray,
            slot_offsets: np.ndarray, n: np.ndarray, width: np.ndarray, straight: np.ndarray
            ) -> np.ndarray:
    """Per line, whether an edge of one of its bounds runs against the centreline edge it
    follows (a fold); straight bounds are checked against the chord."""
    line = np.repeat(np.arange(len(n)), n + 1)
    k = np.arange(slot_offsets[-1]) - slot_offsets[line]
    count = np.where(straight, 2, np.diff(coff))[line]  # vertices of each bound
    bound = np.repeat(np.arange(len(line)), count)
    j = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    s = line[bound]
    centre = np.where(straight[s], np.where(j == 0, coff[:-1][s], coff[1:][s] - 1),
                      coff[:-1][s] + j)
    points = cxy[centre] + ((n[s] / 2.0 - k[bound]) * width[s])[:, None] * normals[centre]
    first = np.cumsum(count) - count
    points[first], points[first + count - 1] = end_xy[0], end_xy[1]
    along = np.einsum("ij,ij->i", np.diff(points, axis=0), np.diff(cxy[centre], axis=0))
    within = np.diff(bound) == 0
    bad = np.zeros(len(n), bool)
    np.logical_or.at(bad, s[:-1][within & (along <= 0)], True)
    return bad


def _join(arms: topo.Arms, n: np.ndarray, lateral: np.ndarray, cxy: np.ndarray,
          coff: np.ndarray, first_dir: np.ndarray, last_dir: np.ndarray,
          slot_offsets: np.ndarray, end_xy: np.ndarray
          ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """At each joint, give both arms the same bound end points: the mitre of the two
    segments' end edges (in place); returns where they are at the first arm and at the
    second, so both get the first arm's ids."""
    a = _pairs(arms, topo.JOINT)
    b = arms.partner[a]
    sa, ea, sb, eb = a // 2, a % 2, b // 2, b % 2
    m = _through(ea, eb, sa, sb, first_dir, last_dir)
    at = np.where(ea == 1, coff[1:][sa] - 1, coff[:-1][sa])
    count = n[sa] + 1
    j = np.repeat(np.arange(len(a)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    along_a = lateral[ea[j], slot_offsets[sa][j] + k]  # left of a's digitising direction
    through = np.where(ea[j] == 1, along_a, -along_a)
    points = cxy[at][j] + through[:, None] * m[j]
    kb = np.where(ea[j] != eb[j], k, n[sa][j] - k)
    slot_a, slot_b = slot_offsets[sa][j] + k, slot_offsets[sb][j] + kb
    end_xy[ea[j], slot_a] = points
    end_xy[eb[j], slot_b] = points
    return (ea[j], slot_a), (eb[j], slot_b)


def _pairs(arms: topo.Arms, kind: int) -> np.ndarray:
    """The first arm of each pair of partner arms at nodes of ``kind``."""
    return np.flatnonzero((arms.partner >= 0) & (np.arange(len(arms.partner)) < arms.partner)
                          & (arms.kind[arms.node] == kind))


def _through(ea: np.ndarray, eb: np.ndarray, sa: np.ndarray, sb: np.ndarray,
             first_dir: np.ndarray, last_dir: np.ndarray) -> np.ndarray:
    """The mitred left normal of the path "along arm a into the node, then out along b"."""
    na = np.where((ea == 1)[:, None], left_normal(last_dir[sa]), -left_normal(first_dir[sa]))
    nb = np.where((eb == 0)[:, None], left_normal(first_dir[sb]), -left_normal(last_dir[sb]))
    return mitre(na, nb)


TAPER_M = 5.0
"""Over how much of its length a lane that opens widens (or one that ends narrows): the
stored ranges say where the lane count changes, not the taper's shape."""
OPEN_MATCH_M = 1.0
"""How far apart a bound on either side of an opening may end and still be one bound."""
MOVED_M = 0.05
"""A bound of the side with more lanes moved further than this to its shared point gets back
to its own offset over :data:`TAPER_M` (lanes of 3.0 and 3.5 m after 3 m ones)."""


def _open(arms: topo.Arms, lateral: np.ndarray, cxy: np.ndarray, coff: np.ndarray,
          first_dir: np.ndarray, last_dir: np.ndarray, slot_offsets: np.ndarray,
          end_xy: np.ndarray, tapered: np.ndarray
          ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray], np.ndarray,
                     list[tuple[int, int, float]]]:
    """At each opening, the bounds of the side with fewer lanes and the bounds of the other
    side lying within :data:`OPEN_MATCH_M` of them share their end points (mitred, at the
    fewer lanes' offsets); each other bound of the side with more lanes starts (or ends) at
    the shared point nearest it, so the lane it bounds opens (or closes) from a point. Sets
    ``end_xy`` in place; returns where the shared points are on the first side and on the
    second, as :func:`_join`, the openings whose bounds do not match that way, and the bounds
    moved to a shared point (more than :data:`MOVED_M`) as (slot, end, the offset left of
    their line they had there): each reaches that offset again :data:`TAPER_M` from the
    node (:func:`app.lanelet2.build.taper_points`), the lane widening over that length.
    A bound whose paint runs over from another's offset (``tapered``, (2, slots): the
    painted taper of :func:`ingest.lanes.assign._tapered`) starts at that bound's point and
    follows its paint, with no taper of :data:`TAPER_M` of its own: it is the lane that
    opens, whatever lies near it at the node."""
    a = _pairs(arms, topo.OPENING)
    b = arms.partner[a]
    sa, ea, sb, eb = a // 2, a % 2, b // 2, b % 2
    m = _through(ea, eb, sa, sb, first_dir, last_dir)
    firsts: list[tuple[int, int]] = []
    seconds: list[tuple[int, int]] = []
    unmatched: list[int] = []
    tapers: list[tuple[int, int, float]] = []
    for i in range(len(a)):
        sides = []  # (end, slots, offsets left of the path) of each arm
        for s, e, into in ((sa[i], ea[i], ea[i] == 1), (sb[i], eb[i], eb[i] == 0)):
            slots = np.arange(slot_offsets[s], slot_offsets[s + 1])
            sides.append((int(e), slots, np.where(into, 1.0, -1.0) * lateral[e, slots],
                          tapered[e, slots]))
        few, many = sorted(sides, key=lambda side: len(side[1]))
        nearest = np.abs(many[2][:, None] - few[2][None, :]).argmin(axis=1)
        gap = np.abs(many[2] - few[2][nearest])
        shared = (gap <= OPEN_MATCH_M) & ~many[3]
        if len(set(nearest[shared].tolist())) != len(few[1]) or shared.sum() != len(few[1]):
            unmatched.append(int(arms.node[a[i]]))
            continue
        at = coff[1:][sa[i]] - 1 if ea[i] == 1 else coff[:-1][sa[i]]
        points = cxy[at] + few[2][:, None] * m[i]
        end_xy[few[0], few[1]] = points
        end_xy[many[0], many[1]] = points[nearest]
        tapers += [(int(slot), many[0], float(lateral[many[0], slot]))
                   for slot in many[1][(gap > MOVED_M) & ~many[3]]]
        firsts += [(few[0], int(few[1][j])) for j in nearest]
        seconds += [(many[0], int(slot)) for slot in many[1]]

    def split(pairs: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
        out = np.array(pairs, np.int64).reshape(-1, 2)
        return out[:, 0], out[:, 1]

    return split(firsts), split(seconds), np.array(unmatched, np.int64), tapers
