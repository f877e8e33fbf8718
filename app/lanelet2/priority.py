"""Who gives way at a junction, read from the painted stop lines.

Without a ``right_of_way`` element lanelet2 treats an intersection as first come, first
served, and Autoware's intersection module has nothing to tell the major road from the
minor one. The paint says it where it was read: at a junction without a traffic light, an
approach with a painted stop line (a stop sign's line, ``traffic_sign`` element) gives way
to the approaches whose paint was read and shows none, and where every approach has one it
is an all-way stop.

- **right_of_way**, one element per stopping approach (lanelet2's element has one
  ``ref_line``): its entering lanelets ``yield``, those of every approach read without a stop
  line have ``right_of_way``, the stop line is the ``ref_line``. Approaches nobody read the
  paint of are in neither role: nothing is known of them.
- **all_way_stop**, one element per junction whose every approach has a stop line: every
  entering lanelet ``yield``, the stop lines as ``ref_line`` in the same order (one per
  lanelet, as lanelet2 requires), the stop signs as ``refers``.

The lanelets named are the last ones of each approach before the junction, as lanelet2's
tagging guide asks, and each references the element. A stop line a few metres before the
junction cuts its road into pieces (:mod:`app.lanelet2.paint`): the stop is followed through
those joints, and through the openings where a lane opens or ends between the line and the
junction, up to :data:`STOP_REACH_M`, to the junction it belongs to. Junctions with a
traffic light get neither (the light's element governs), nor do nodes of fewer than three
roads (nothing crosses there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.lanelet2 import topology as topo
from app.lanelet2.frame import IdSource

STOP_REACH_M = 30.0
"""How far before a junction a stop line still belongs to it."""


@dataclass(frozen=True)
class Priority:
    """One right-of-way element: its id, kind, and the arms (entering lanes) in each role."""

    element: int
    kind: str
    """``right_of_way`` or ``all_way_stop``."""
    node: int
    """Index of the junction node."""
    yielding: tuple[int, ...]
    """Arms whose entering lanelets yield."""
    stops: tuple[int, ...]
    """The stop line arm of each yielding arm (where its stop line lies), same order."""
    priority: tuple[int, ...] = ()
    """Arms whose entering lanelets have the right of way (``right_of_way`` only)."""


def junction_arm(arm: int, arms: topo.Arms, length_m: np.ndarray) -> int | None:
    """The arm at which lanes entering at ``arm`` (a stop line's) reach a junction: ``arm``
    itself, or the entering arm past the joints and openings (a turning lane that opens
    after the line) that follow it, within :data:`STOP_REACH_M`; None when they end
    elsewhere first."""
    walked = 0.0
    while arms.kind[arms.node[arm]] in (topo.JOINT, topo.OPENING):
        following = int(arms.partner[arm]) ^ 1  # the next piece's other end
        walked += float(length_m[following // 2])
        if walked > STOP_REACH_M:
            return None
        arm = following
    return arm if arms.kind[arms.node[arm]] == topo.JUNCTION else None


def plan_priorities(arms: topo.Arms, traffic_light: np.ndarray, painted: np.ndarray,
                    stop_arms: list[int], length_m: np.ndarray, ids: IdSource
                    ) -> list[Priority]:
    """The right-of-way elements of a layout (module docstring): ``painted`` says per road
    row whether its paint was read, ``stop_arms`` are the arms of unlit painted stop lines."""
    stops_at: dict[int, int] = {}
    for stop in sorted(stop_arms):
        at = junction_arm(stop, arms, length_m)
        if at is not None:
            stops_at.setdefault(at, stop)
    out: list[Priority] = []
    for node in sorted({int(arms.node[a]) for a in stops_at}):
        members = arms.order[arms.starts[node]:arms.starts[node + 1]].tolist()
        if traffic_light[node] or len(members) < 3:
            continue
        entering = [a for a in members if arms.lanes_in[a] > 0]
        yielding = [a for a in entering if a in stops_at]
        priority = [a for a in entering if a not in stops_at and painted[a // 2]]
        stops = tuple(stops_at[a] for a in yielding)
        if len(yielding) == len(entering):
            out.append(Priority(int(ids.take(1)[0]), "all_way_stop", node, tuple(yielding),
                                stops))
        elif priority:
            out += [Priority(int(ids.take(1)[0]), "right_of_way", node, (a,), (s,),
                             tuple(priority)) for a, s in zip(yielding, stops, strict=True)]
    return out


def elements_by_arm(priorities: list[Priority]) -> dict[int, list[int]]:
    """arm -> the right-of-way elements its entering lanelets must reference."""
    out: dict[int, list[int]] = {}
    for p in priorities:
        for arm in (*p.yielding, *p.priority):
            out.setdefault(arm, []).append(p.element)
    return out


def priority_relation(p: Priority, lanelets: dict[int, list[int]],
                      stop_ways: dict[int, tuple[int, int]], node_id: int
                      ) -> tuple[int, list[tuple[str, int, str]], dict[str, object]]:
    """The element's relation: ``lanelets`` are the entering lanelet ids by arm,
    ``stop_ways`` the (stop line, stop sign) way ids by stop arm."""
    yielding = [(ll, stop) for arm, stop in zip(p.yielding, p.stops, strict=True)
                for ll in lanelets[arm]]
    members = [("relation", ll, "yield") for ll, _ in yielding]
    if p.kind == "all_way_stop":
        members += [("way", stop_ways[stop][0], "ref_line") for _, stop in yielding]
        members += [("way", stop_ways[stop][1], "refers") for stop in p.stops]
    else:
        members += [("relation", ll, "right_of_way") for arm in p.priority
                    for ll in lanelets[arm]]
        members.append(("way", stop_ways[p.stops[0]][0], "ref_line"))
    return p.element, members, {"type": "regulatory_element", "subtype": p.kind,
                                "node_id": node_id, "ugvmap:source": "paint"}
