"""Junction lanelets and traffic lights: what is written at each node.

At a junction every incoming lane is joined to the outgoing lanes of every *other* road by
a lanelet tagged ``turn_direction`` (straight within 30°), ``segment_id`` (the road left),
``to_segment_id`` and ``node_id``, with ``virtual`` bounds. lanelet2's loader turns a
lanelet's bounds round by a heuristic (which side of one bound the other's middle point
lies), so each is drawn the first of several ways the heuristic reads as written, and left
out (reported) when none does. At a node flagged ``traffic_light`` each road entering it gets
a ``traffic_light`` regulatory element, its ``ref_line`` a ``stop_line`` across the lanes
where they end and ``refers`` a ``traffic_light`` linestring (0.5 m wide, ``height`` 1.0,
1 m right of the road at the stop line, 5 m up: its nodes' ``ele``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from app.lanelet2.frame import Frame, IdSource
from app.lanelet2.geometry import (
    bounds_oriented,
    lane_curves,
    left_normal,
    signed_turn_deg,
    spread_lanes,
    straight_points,
    turn_curves,
)
from app.lanelet2.layout import Layout
from app.lanelet2.osm_xml import Member, OsmXmlWriter
from app.routing.profiles import CAR

STRAIGHT_DEG = 30.0
LIGHT_HEIGHT_M = 5.0
LIGHT_WIDTH_M = 0.5
LIGHT_BOX_HEIGHT_M = 1.0
LIGHT_OFFSET_M = 1.0
VIRTUAL: dict[str, object] = {"type": "virtual"}
BASE_TAGS = {"type": "lanelet", "subtype": "road", "location": "urban", "one_way": "yes",
             "participant:vehicle": "yes"}


def vehicle_tags(*road_classes: str) -> dict[str, str]:
    """``participant:vehicle=no`` on a lanelet of a road class a car never drives (a footway,
    cycleway, steps: :data:`app.routing.profiles.CAR`), or joining one: the map says what
    ugvmap's own car routing says, so a planner on the Lanelet2 map cannot take the footway
    shortcut the router refuses. Those lanelets stay in the map (a sidewalk robot's stack
    may read them)."""
    if any(CAR.forbids(c) for c in road_classes):
        return {"participant:vehicle": "no", "participant:pedestrian": "yes"}
    return {}


def speed_tag(kph: float) -> str:
    """``speed_limit`` as lanelet2 reads it: km/h without a unit."""
    return f"{kph:.0f}" if float(kph).is_integer() else f"{kph:.1f}"


@dataclass
class Lane:
    """A lane where it meets a junction: its bound end points, left and right."""

    left_id: int
    right_id: int
    left_xy: np.ndarray
    right_xy: np.ndarray


def arm_lanes(plan: Layout, arm: int, entering: bool) -> list[Lane]:
    """The lanes entering (or leaving) the node along ``arm``, rightmost first."""
    s, e = divmod(arm, 2)
    f, b = int(plan.forward[s]), int(plan.backward[s])
    base = plan.slot_offsets[s]
    along = (e == 1) == entering  # the lanes run along the geometry: forward lanes
    if along:
        pairs = [(base + b + j, base + b + j + 1) for j in range(f)][::-1]
    else:
        pairs = [(base + j + 1, base + j) for j in range(b)]
    return [Lane(int(plan.end_ids[e][lft]), int(plan.end_ids[e][rgt]), plan.end_xy[e][lft],
                  plan.end_xy[e][rgt]) for lft, rgt in pairs]


@dataclass
class Pending:
    """Bounds (curves to sample) and lanelets of a batch of junctions."""

    connectors: list[tuple[int, Lane, Lane, np.ndarray, np.ndarray, int,
                           dict[str, object]]] = field(default_factory=list)
    relations: list[tuple[int, list[Member], dict[str, object]]] = field(default_factory=list)
    ways: list[tuple[int, list[int], dict[str, object]]] = field(default_factory=list)
    light_points: list[tuple[int, np.ndarray]] = field(default_factory=list)


def junction(plan: Layout, node: int, ids: IdSource, pending: Pending) -> int:
    """Connecting lanelets of junction ``node``; returns how many."""
    arms = plan.arms
    members = arms.order[arms.starts[node]:arms.starts[node + 1]].tolist()
    made = 0
    for a in members:
        ins = arm_lanes(plan, a, entering=True)
        if not ins:
            continue
        heading_in = -plan.away[a]
        for b in members:
            outs = arm_lanes(plan, b, entering=False)
            if b == a or not outs:
                continue
            turn = float(signed_turn_deg(heading_in[None], plan.away[b][None])[0])
            direction = ("straight" if abs(turn) <= STRAIGHT_DEG
                         else "left" if turn > 0 else "right")
            samples = 2 + round(abs(turn) / 30.0)
            # Lanes pair up from the side the turn goes to: rightmost to rightmost for right
            # turns and straight on, leftmost to leftmost for left turns.
            ordered_in, ordered_out = ((ins[::-1], outs[::-1]) if direction == "left"
                                       else (ins, outs))
            sa, sb = a // 2, b // 2
            tags = {**BASE_TAGS, **vehicle_tags(plan.roads.road_class[sa],
                                                plan.roads.road_class[sb]),
                    "speed_limit": speed_tag(min(plan.speed[sa], plan.speed[sb])),
                    "turn_direction": direction, "segment_id": int(plan.roads.ids[sa]),
                    "to_segment_id": int(plan.roads.ids[sb]),
                    "node_id": int(plan.node_ids[node])}
            for i in range(max(len(ins), len(outs))):
                lane_in = ordered_in[min(i, len(ins) - 1)]
                lane_out = ordered_out[min(i, len(outs) - 1)]
                pending.connectors.append((int(ids.take(1)[0]), lane_in, lane_out, heading_in,
                                           plan.away[b], samples, tags))
                made += 1
    return made


def lights(plan: Layout, node: int, ids: IdSource, pending: Pending) -> int:
    """A stop line, a light and a traffic-light element for each road entering ``node``."""
    arms = plan.arms
    made = 0
    for a in arms.order[arms.starts[node]:arms.starts[node + 1]].tolist():
        if not plan.re_ids[a]:
            continue
        ins = arm_lanes(plan, a, entering=True)
        stop_line, light = ids.take(2).tolist()
        rightmost, leftmost = ins[0], ins[-1]
        heading = -plan.away[a]
        left_n = left_normal(heading[None])[0]
        centre = rightmost.right_xy - LIGHT_OFFSET_M * left_n
        corners = ids.take(2).tolist()
        pending.light_points += [(corners[0], centre + LIGHT_WIDTH_M / 2 * left_n),
                                 (corners[1], centre - LIGHT_WIDTH_M / 2 * left_n)]
        pending.ways += [(stop_line, [leftmost.left_id, rightmost.right_id],
                          {"type": "stop_line"}),
                         (light, corners, {"type": "traffic_light", "subtype": "red_yellow_green",
                                           "height": f"{LIGHT_BOX_HEIGHT_M:.1f}"})]
        pending.relations.append((int(plan.re_ids[a]),
                                  [("way", light, "refers"), ("way", stop_line, "ref_line")],
                                  {"type": "regulatory_element", "subtype": "traffic_light",
                                   "node_id": int(plan.node_ids[node])}))
        made += 1
    return made


def flush(pending: Pending, frame: Frame, ids: IdSource, out: OsmXmlWriter
           ) -> list[tuple[int, int, int]]:
    """Draw the pending junction lanelets (vectorised per sample count), drop those lanelet2
    would read with a bound turned round however drawn (their roads overlap where they meet),
    write everything; returns the dropped movements as (node, from segment, to segment)."""
    by_samples: dict[int, list[int]] = {}
    for i, item in enumerate(pending.connectors):
        by_samples.setdefault(item[5], []).append(i)
    ways: list[tuple[int, list[int], dict[str, object]]] = []
    relations: list[tuple[int, list[Member], dict[str, object]]] = []
    dropped: list[tuple[int, int, int]] = []
    for samples, which in sorted(by_samples.items()):
        items = [pending.connectors[i] for i in which]
        lanes_in, lanes_out = [it[1] for it in items], [it[2] for it in items]
        ends = [np.array([getattr(lane, side) for lane in lanes])
                for lanes, side in ((lanes_in, "left_xy"), (lanes_in, "right_xy"),
                                    (lanes_out, "left_xy"), (lanes_out, "right_xy"))]
        heading_in = np.array([it[3] for it in items])
        heading_out = np.array([it[4] for it in items])
        # Several ways to draw the turn; the first lanelet2 reads as written is kept.
        shapes = [(turn_curves(ends[0], heading_in, ends[2], heading_out, samples),
                   turn_curves(ends[1], heading_in, ends[3], heading_out, samples)),
                  lane_curves(ends[0], ends[1], heading_in, ends[2], ends[3], heading_out,
                              samples),
                  (straight_points(ends[0], ends[2], samples),
                   straight_points(ends[1], ends[3], samples)),
                  spread_lanes(ends[0], ends[1], heading_in, ends[2], ends[3], heading_out,
                               samples)]
        lefts, rights = shapes[0]
        good = np.zeros(len(items), bool)
        for shape_left, shape_right in shapes:
            for i in np.flatnonzero(~good).tolist():
                if bounds_oriented(np.vstack([ends[0][i], shape_left[i], ends[2][i]]),
                                   np.vstack([ends[1][i], shape_right[i], ends[3][i]])):
                    good[i] = True
                    lefts[i], rights[i] = shape_left[i], shape_right[i]
        dropped += [(int(str(t["node_id"])), int(str(t["segment_id"])),
                     int(str(t["to_segment_id"])))
                    for *_, t in (items[i] for i in np.flatnonzero(~good).tolist())]
        keep = np.flatnonzero(good)
        if not len(keep):
            continue
        local = np.concatenate([lefts[keep], rights[keep]]).reshape(-1, 2)
        point_ids = ids.take(len(local)).reshape(2, len(keep), samples)
        out.nodes(point_ids.ravel(), frame.lonlat(local), local)
        way_ids = ids.take(2 * len(keep)).reshape(2, -1)
        for j, i in enumerate(keep.tolist()):
            lanelet_id, lane_in, lane_out, *_, tags = items[i]
            left, right = int(way_ids[0, j]), int(way_ids[1, j])
            ways += [(left, [lane_in.left_id, *point_ids[0, j].tolist(), lane_out.left_id],
                      VIRTUAL),
                     (right, [lane_in.right_id, *point_ids[1, j].tolist(), lane_out.right_id],
                      VIRTUAL)]
            relations.append((lanelet_id, [("way", left, "left"), ("way", right, "right")],
                              tags))
    out.ways(ways)
    if pending.light_points:
        pids = np.array([p for p, _ in pending.light_points], np.int64)
        local = np.array([xy for _, xy in pending.light_points])
        out.nodes(pids, frame.lonlat(local), local, LIGHT_HEIGHT_M)
    out.ways(pending.ways)
    out.relations(relations + pending.relations)
    return dropped
