"""Turn a network selection into a Lanelet2 map, streamed into an :class:`OsmXmlWriter`.

Conventions (the README's *Lanelet2 export* section says the same for users):

- **Frame** (:mod:`app.lanelet2.frame`): metres in the UTM zone of the map origin,
  relative to it, as lanelet2's ``UtmProjector`` computes; ``ele`` is 0 (no heights).
- **Cross-section.** A segment's lanes are centred on its line, lane width apart, backward
  lanes on the left of the digitising direction and forward lanes on the right (right-hand
  traffic). Bounds between lanes of one direction are ``line_thin``/``dashed`` (lane changes
  allowed), between the two directions ``line_thin``/``solid``, at the road's edges
  ``road_border``; lanelets beside each other share their bound (one way, written once).
- **Lanelets.** One per lane and allowed direction, ``type=lanelet subtype=road
  location=urban one_way=yes participant:vehicle=yes speed_limit=<km/h>`` (the segment's
  limit, else the router's class default; ``participant:vehicle=no`` on classes a car never
  drives, as ugvmap's car routing), ``segment_id``, ``direction`` (forward/backward
  along the segment's geometry) and ``lane`` (1 = the rightmost); junction lanelets carry
  ``turn_direction`` (straight within 30°), ``segment_id`` (the segment they leave),
  ``to_segment_id``, ``node_id`` and ``virtual`` bounds (nothing is painted in a junction).
- **Junctions and traffic lights**: :mod:`app.lanelet2.junctions`.
- **Who gives way** (``right_of_way``, ``all_way_stop``, from painted stop lines):
  :mod:`app.lanelet2.priority`.

IDs are positive, unique across nodes, ways and relations, and handed out in a fixed order
(segments by id, nodes by id), so the same network gives the same file byte for byte.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
import shapely

from app.lanelet2 import topology as topo
from app.lanelet2.frame import Frame, IdSource
from app.lanelet2.geometry import bounds_oriented, line_index, progressing
from app.lanelet2.junctions import (
    BASE_TAGS,
    Pending,
    flush,
    junction,
    lights,
    speed_tag,
    vehicle_tags,
)
from app.lanelet2.layout import TAPER_M, Layout, plan_layout
from app.lanelet2.osm_xml import Member, OsmXmlWriter
from app.lanelet2.priority import elements_by_arm, priority_relation
from app.lanelet2.roads import NetworkSelection

Progress = Callable[[str, float], None]
SEGMENT_CHUNK = 20_000
SIGN_HEIGHT_M = 2.0
NODE_CHUNK = 20_000


@dataclass
class MapSummary:
    """What a Lanelet2 export wrote."""

    segments: int  # segments mapped
    lanelets: int
    junction_lanelets: int
    traffic_lights: int
    # Junction lanelets not drawn, as (node, from segment, to segment): where the roads overlap
    # at a node, lanelet2 would read every drawing of the turn with a bound turned round.
    movements_dropped: list[tuple[int, int, int]]
    defects: list[topo.Defect] = field(default_factory=list)
    elements: dict[str, int] = field(default_factory=dict)
    from_paint: dict[str, int] = field(default_factory=dict)
    """What the paint added besides the lanes' bounds (stop lines, right-of-way elements,
    crosswalks), where any."""


def _boundary_tags(k: int, n: int, backward: int) -> dict[str, str]:
    if k in (0, n):
        return {"type": "road_border"}
    if k == backward:
        return {"type": "line_thin", "subtype": "solid"}
    return {"type": "line_thin", "subtype": "dashed"}


def _segment_tags(plan: Layout, s: int) -> dict[str, object]:
    roads = plan.roads
    tags: dict[str, object] = {**BASE_TAGS, **vehicle_tags(roads.road_class[s]),
                               "speed_limit": speed_tag(plan.speed[s]),
                               "segment_id": int(roads.ids[s]),
                               "road_class": roads.road_class[s]}
    if roads.name[s]:
        tags["name"] = roads.name[s]
    return tags


def _write_end_points(plan: Layout, frame: Frame, out: OsmXmlWriter) -> None:
    ids = plan.end_ids.ravel()
    unique, first = np.unique(ids, return_index=True)
    local = plan.end_xy.reshape(-1, 2)[first]
    out.nodes(unique, frame.lonlat(local), local)


def _write_segments(plan: Layout, frame: Frame, ids: IdSource, out: OsmXmlWriter,
                    rows: range, priority: dict[int, list[int]],
                    entering: dict[int, list[int]]) -> int:
    """Bounds and lanelets of segments ``rows``; returns the number of lanelets. Lanelets
    entering a junction at an arm of ``priority`` reference its right-of-way elements and
    are added to that arm's list in ``entering``."""
    n = plan.forward + plan.backward
    seg_rows = np.arange(rows.start, rows.stop)
    slots = np.arange(plan.slot_offsets[rows.start], plan.slot_offsets[rows.stop])
    slot_seg = np.repeat(seg_rows, n[seg_rows] + 1)
    k = slots - plan.slot_offsets[slot_seg]
    inner = plan.offsets[1:][slot_seg] - plan.offsets[:-1][slot_seg] - 2
    inner_offsets = np.concatenate([[0], np.cumsum(inner)])
    vertex = (np.repeat(plan.offsets[:-1][slot_seg] + 1 - inner_offsets[:-1], inner)
              + np.arange(inner_offsets[-1]))
    offset = np.repeat((n[slot_seg] / 2.0 - k) * plan.width[slot_seg], inner)
    local = plan.xy[vertex] + offset[:, None] * plan.normals[vertex]
    # Keep each bound running forwards along its centreline (no folds on tight bends).
    centre_at = np.arange(plan.offsets[rows.start], plan.offsets[rows.stop])
    centres = shapely.linestrings(plan.xy[centre_at],
                                  indices=line_index(plan.offsets[rows.start:rows.stop + 1]
                                                     - plan.offsets[rows.start]))
    slot_line = slot_seg - rows.start
    point_slot = np.repeat(np.arange(len(slots)), inner)

    def along(lines: np.ndarray, xy: np.ndarray) -> np.ndarray:
        return shapely.line_locate_point(lines, shapely.points(xy))

    keep = progressing(along(centres[slot_line[point_slot]], local), point_slot,
                       along(centres[slot_line], plan.end_xy[0][slots]),
                       along(centres[slot_line], plan.end_xy[1][slots]))
    local, point_slot = _painted_inner(plan, rows, slots, local[keep], point_slot[keep])
    local, point_slot = taper_points(plan, slots, local, point_slot)
    inner_offsets = np.concatenate([[0], np.cumsum(np.bincount(point_slot,
                                                               minlength=len(slots)))])
    point_ids = ids.take(len(local))
    out.nodes(point_ids, frame.lonlat(local), local)
    way_ids = ids.take(len(slots))
    starts, ends = plan.end_ids[0][slots].tolist(), plan.end_ids[1][slots].tolist()
    pid = point_ids.tolist()
    io = inner_offsets.tolist()
    painted = plan.pieces.slots
    out.ways((int(way_ids[i]), [starts[i], *pid[io[i]:io[i + 1]], ends[i]],
              painted[key].tags if (key := (int(slot_seg[i]), int(k[i]))) in painted else
              _boundary_tags(int(k[i]), int(n[slot_seg[i]]), int(plan.backward[slot_seg[i]])))
             for i in range(len(slots)))
    relations: list[tuple[int, list[Member], dict[str, object]]] = []
    lanelet_ids = ids.take(int(n[seg_rows].sum()))
    next_lanelet = 0
    base = plan.slot_offsets[rows.start]
    for s in seg_rows.tolist():
        tags = _segment_tags(plan, s)
        f, b = int(plan.forward[s]), int(plan.backward[s])
        w0 = plan.slot_offsets[s] - base
        for direction, count, arm in (("forward", f, 2 * s + 1), ("backward", b, 2 * s)):
            re_id = int(plan.re_ids[arm])
            for j in range(count):
                if direction == "forward":  # lane j of the forward lanes, from their left
                    left, right, lane = w0 + b + j, w0 + b + j + 1, f - j
                else:  # the loader turns both bounds round (they point along the geometry)
                    left, right, lane = w0 + j + 1, w0 + j, j + 1
                members: list[Member] = [("way", int(way_ids[left]), "left"),
                                         ("way", int(way_ids[right]), "right")]
                members += [("relation", r, "regulatory_element")
                            for r in (re_id, plan.stop_ids.get(arm, 0), *priority.get(arm, ()))
                            if r]
                lanelet = int(lanelet_ids[next_lanelet])
                relations.append((lanelet, members,
                                  {**tags, "direction": direction, "lane": lane}))
                if arm in entering:
                    entering[arm].append(lanelet)
                next_lanelet += 1
    out.relations(relations)
    return len(relations)


def _painted_inner(plan: Layout, rows: range, slots: np.ndarray, local: np.ndarray,
                   point_slot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The inner points of the chunk's bounds with those of painted bounds replaced by the
    paint's vertices between the line's cuts (``point_slot``: index into ``slots``). Where
    lanelet2's loader would read a lanelet of the piece with a bound turned round (paint
    that strays across the piece's centreline where the segment leaves the road), the
    piece keeps the bounds offset from its centreline (through the paint's end points)."""
    if not plan.pieces.slots:
        return local, point_slot
    base = plan.slot_offsets[rows.start]
    inner: dict[int, np.ndarray] = {}
    for s in sorted({s for s, _ in plan.pieces.slots if rows.start <= s < rows.stop}):
        first = int(plan.slot_offsets[s] - base)
        count = int(plan.slot_offsets[s + 1] - plan.slot_offsets[s])
        mine = {first + k: slot.inner(float(plan.cut[0, s]), float(plan.cut[1, s]))
                for k in range(count) if (slot := plan.pieces.slots.get((s, k))) is not None}
        bounds = [np.vstack([plan.end_xy[0][base + i],
                             mine[i] if i in mine else local[point_slot == i],
                             plan.end_xy[1][base + i]]) for i in range(first, first + count)]
        if all(bounds_oriented(left, right) for left, right in itertools.pairwise(bounds)):
            inner.update(mine)
    keep = ~np.isin(point_slot, list(inner))
    xy = np.concatenate([local[keep], *inner.values()])
    which = np.concatenate([point_slot[keep], *[np.full(len(v), i) for i, v in inner.items()]])
    order = np.argsort(which, kind="stable")
    return xy[order], which[order]


def taper_points(plan: Layout, slots: np.ndarray, local: np.ndarray, point_slot: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The inner points of the chunk's bounds (``point_slot``: index into ``slots``) with
    each bound an opening pulled to a point (``Layout.tapers``) given a point back at its own
    offset :data:`~app.lanelet2.layout.TAPER_M` from that end (at most half its line), its
    inner points nearer that end dropped: the lane widens from nothing over that length, then
    runs as stored (without it, a straight piece's bound went straight to its far end and
    the new lane was half as wide halfway along)."""
    where = {int(slot): i for i, slot in enumerate(slots.tolist())}
    mine = [(where[slot], end, offset) for slot, end, offset in plan.tapers if slot in where]
    if not mine:
        return local, point_slot
    keep = np.ones(len(local), bool)
    extra, extra_slot, extra_key = [], [], []
    for i, end, offset in mine:
        s = int(np.searchsorted(plan.slot_offsets, slots[i], side="right") - 1)
        centre = shapely.LineString(plan.xy[plan.offsets[s]:plan.offsets[s + 1]])
        reach = min(TAPER_M, centre.length / 2)
        station = reach if end == 0 else centre.length - reach
        ahead, behind = (shapely.get_coordinates(centre.interpolate(station + d))[0]
                         for d in (0.5, -0.5))
        tangent = (ahead - behind) / max(float(np.hypot(*(ahead - behind))), 1e-9)
        at = shapely.get_coordinates(centre.interpolate(station))[0]
        extra.append(at + offset * np.array([-tangent[1], tangent[0]]))
        extra_slot.append(i)
        extra_key.append(-1 if end == 0 else len(local))
        own = np.flatnonzero(point_slot == i)
        along = shapely.line_locate_point(centre, shapely.points(local[own]))
        keep[own[along < reach if end == 0 else along > centre.length - reach]] = False
    xy = np.concatenate([local[keep], np.array(extra)])
    which = np.concatenate([point_slot[keep], extra_slot])
    key = np.concatenate([np.flatnonzero(keep), extra_key])
    order = np.lexsort((key, which))
    return xy[order], which[order]


def _write_stops(plan: Layout, frame: Frame, ids: IdSource, out: OsmXmlWriter
                 ) -> dict[int, tuple[int, int]]:
    """Painted stop lines as ``traffic_sign`` regulatory elements (a stop sign beside the
    road where the line ends, as Autoware's maps draw a stop line without a light), each
    referenced by the lanelets that end at it; a stop line before a traffic light is only
    its ``stop_line`` way (the light's element governs those lanes: a stop sign there would
    make the vehicle stop on green). Returns the (stop line, stop sign) way ids by arm."""
    ways: list[tuple[int, list[int], dict[str, object]]] = []
    relations: list[tuple[int, list[Member], dict[str, object]]] = []
    written: dict[int, tuple[int, int]] = {}
    for stop in plan.pieces.stops:
        if stop.lit:
            line = int(ids.take(1)[0])
            points = ids.take(2)
            out.nodes(points, frame.lonlat(stop.xy), stop.xy)
            ways.append((line, points.tolist(), {"type": "stop_line", "ugvmap:source": "paint"}))
            continue
        line, sign = ids.take(2).tolist()
        along = stop.xy[1] - stop.xy[0]
        along = along / max(float(np.hypot(*along)), 1e-9)
        sign_xy = np.array([stop.xy[1] + 0.5 * along, stop.xy[1] + 1.0 * along])
        points = ids.take(4)
        out.nodes(points[:2], frame.lonlat(stop.xy), stop.xy)
        out.nodes(points[2:], frame.lonlat(sign_xy), sign_xy, SIGN_HEIGHT_M)
        ways += [(line, points[:2].tolist(), {"type": "stop_line", "ugvmap:source": "paint"}),
                 (sign, points[2:].tolist(), {"type": "traffic_sign", "subtype": "stop_sign",
                                              "virtual": "yes"})]
        written[stop.arm] = (line, sign)
        relations.append((plan.stop_ids[stop.arm], [("way", sign, "refers"),
                                                    ("way", line, "ref_line")],
                          {"type": "regulatory_element", "subtype": "traffic_sign",
                           "segment_id": int(plan.roads.ids[stop.arm // 2])}))
    out.ways(ways)
    out.relations(relations)
    return written


def _write_crossings(plan: Layout, frame: Frame, ids: IdSource, out: OsmXmlWriter) -> int:
    """Painted pedestrian crossings as ``crosswalk`` lanelets (pedestrians only, both ways):
    bounds of type ``zebra_marking`` either side of the line across the road, half the
    crossing's reach along the road each way, so lanelet2 sees where it overlaps the road's
    lanelets. Returns how many."""
    ways: list[tuple[int, list[int], dict[str, object]]] = []
    relations: list[tuple[int, list[Member], dict[str, object]]] = []
    for crossing in plan.pieces.crossings:
        start, end = crossing.xy
        across = (end - start) / max(float(np.hypot(*(end - start))), 1e-9)
        left = np.array([-across[1], across[0]]) * crossing.width_m / 2
        local = np.array([start + left, end + left, start - left, end - left])
        points = ids.take(4)
        out.nodes(points, frame.lonlat(local), local)
        left_way, right_way, lanelet = ids.take(3).tolist()
        ways += [(left_way, points[:2].tolist(), {"type": "zebra_marking"}),
                 (right_way, points[2:].tolist(), {"type": "zebra_marking"})]
        relations.append((lanelet, [("way", left_way, "left"), ("way", right_way, "right")],
                          {"type": "lanelet", "subtype": "crosswalk", "one_way": "no",
                           "participant:pedestrian": "yes",
                           "segment_id": int(plan.roads.ids[crossing.row]),
                           "ugvmap:source": "paint"}))
    out.ways(ways)
    out.relations(relations)
    return len(relations)


def _chunks(total: int, size: int) -> Iterator[range]:
    for start in range(0, total, size):
        yield range(start, min(start + size, total))


def write_map(sel: NetworkSelection, frame: Frame, out: OsmXmlWriter,
              progress: Progress | None = None) -> MapSummary:
    """Write the Lanelet2 map of ``sel`` into ``out``; ``progress(stage, fraction)`` hears how
    far it is (planning ~10 %, segments ~50 %, junctions ~40 %)."""
    say: Progress = progress or (lambda _m, _f: None)
    ids = IdSource()
    say("planning lanes and junctions", 0.0)
    plan = plan_layout(sel, frame, ids)
    _write_end_points(plan, frame, out)
    total = len(plan.roads)
    lanelets = 0
    priority = elements_by_arm(plan.priorities)
    entering: dict[int, list[int]] = {arm: [] for arm in priority}
    for rows in _chunks(total, SEGMENT_CHUNK):
        lanelets += _write_segments(plan, frame, ids, out, rows, priority, entering)
        say("segment lanelets", 0.1 + 0.5 * rows.stop / max(total, 1))
    stop_ways = _write_stops(plan, frame, ids, out)
    out.relations([priority_relation(p, entering, stop_ways, int(plan.node_ids[p.node]))
                   for p in plan.priorities])
    crosswalks = _write_crossings(plan, frame, ids, out)
    junction_lanelets = light_count = 0
    dropped: list[tuple[int, int, int]] = []
    busy = np.flatnonzero((plan.arms.kind == topo.JUNCTION)
                          | (plan.traffic_light & (plan.arms.kind > 0)))
    for part in _chunks(len(busy), NODE_CHUNK):
        pending = Pending()
        for node in busy[part.start:part.stop].tolist():
            if plan.arms.kind[node] == topo.JUNCTION:
                junction_lanelets += junction(plan, node, ids, pending)
            light_count += lights(plan, node, ids, pending)
        dropped += flush(pending, frame, ids, out)
        say("junctions", 0.6 + 0.4 * part.stop / max(len(busy), 1))
    junction_lanelets -= len(dropped)
    painted = {"stop lines": len(plan.pieces.stops),
               "right-of-way / all-way-stop elements": len(plan.priorities),
               "crosswalks": crosswalks}
    return MapSummary(total, lanelets + junction_lanelets, junction_lanelets, light_count,
                      sorted(set(dropped)), plan.defects, dict(out.counts),
                      {k: v for k, v in painted.items() if v})


def summary_lines(summary: MapSummary, limit: int = 20) -> list[str]:
    """The defects as report lines, at most ``limit`` then a count of the rest."""
    lines = [str(d) for d in summary.defects[:limit]]
    if len(summary.defects) > limit:
        lines.append(f"... and {len(summary.defects) - limit} more")
    return lines
