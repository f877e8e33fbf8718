"""Turn-by-turn steps of a leg, as OSRM v5 sends them, so OSRM clients (osrm-text-instructions,
Leaflet Routing Machine) phrase them correctly.

A step is a stretch driven without a maneuver on roads with the same name, ref, lanes, speed
limit and class (the last three are ours: a vehicle planner wants them constant per step).
Maneuver types follow OSRM's meaning:

- ``depart`` / ``arrive`` at the leg's ends (``arrive`` says on which side the point lies);
- ``turn`` onto another road, ``new name`` when going straight onto another road (so clients say
  "Continue onto X", not "Continue straight to stay on X");
- ``continue`` when the road keeps its name (turning, or straight through a change of lanes or
  speed limit), and for u-turns;
- ``roundabout`` on entering a roundabout (OSM ``junction=roundabout|circular``), with the
  ``exit`` number counted over the roundabout's nodes that have a road out, then
  ``exit roundabout`` where the route leaves it.

Modifiers are OSRM's: ``straight``, ``slight``/plain/``sharp`` ``left|right``, ``uturn``.
Each step lists its ``intersections``: the maneuver point first, then every node with three or
more roads passed before the next maneuver, with all roads' bearings, ``entry`` (may be driven
into) and ``in``/``out`` indices.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from app.routing.costs import Cost
from app.routing.geometry import side_of
from app.routing.graph import RoadGraph
from app.routing.junctions import Crossings, Junctions
from app.routing.trace import Trace

STRAIGHT_DEG = 30.0
SLIGHT_DEG = 60.0
PLAIN_DEG = 120.0
UTURN_DEG = 170.0
ON_ROAD_M = 0.5  # an end point this close to the road is on neither side


def modifier(before: float, after: float) -> str:
    """OSRM's turn modifier from the bearing before to the bearing after a maneuver point."""
    delta = (after - before + 540.0) % 360.0 - 180.0  # -180..180, positive = clockwise
    size, side = abs(delta), ("right" if delta > 0 else "left")
    if size <= STRAIGHT_DEG:
        return "straight"
    if size >= UTURN_DEG:
        return "uturn"
    if size <= SLIGHT_DEG:
        return f"slight {side}"
    return side if size <= PLAIN_DEG else f"sharp {side}"


@dataclass
class StepContext:
    """What shaping a leg's steps needs besides the leg."""

    graph: RoadGraph
    junctions: Junctions
    avoid: frozenset[str]
    cost: Cost
    driving_side: str
    encode: Callable[[np.ndarray], Any]


# Per run, what a new step starts at when it changes: name, ref, lanes, speed limit, speed,
# class (compared as one tuple per run; a step's dictionary is made once per step).
Attrs = tuple[str, str, int, float | None, float, str]


@dataclass(frozen=True)
class _Leg:
    """A leg's runs as Python lists, and the roads at each joint: every lookup the grouping
    loop makes, read for the whole leg at once (a grid route has ~300 runs)."""

    t: Trace
    attrs: list[Attrs]
    roundabout: list[bool]
    segment_ids: list[int]
    nodes: list[int]  # graph node where run k ends, for k before the last
    crossings: Crossings  # joint k - 1: between runs k - 1 and k

    @staticmethod
    def of(ctx: StepContext, t: Trace) -> _Leg:
        """Read the leg's runs."""
        s, graph = ctx.graph.segs, ctx.graph
        rows = t.rows
        nodes = np.where(t.f_to[:-1] == 1.0, graph.v[rows[:-1]], graph.u[rows[:-1]])
        lanes = np.where(t.forward, s.lanes_forward[rows], s.lanes_backward[rows])
        attrs: list[Attrs] = [
            (name or "", ref or "", n, None if limit != limit else limit, kph, cls)
            for name, ref, n, limit, kph, cls in zip(
                s.name[rows].tolist(), s.ref[rows].tolist(), lanes.tolist(),
                s.speed_limit[rows].tolist(), graph.speed_kph[rows].tolist(),
                s.road_class[rows].tolist(), strict=True)]
        crossings = ctx.junctions.crossings(
            graph, nodes, (rows[:-1], t.forward[:-1]), (rows[1:], ~t.forward[1:]), ctx.avoid)
        return _Leg(t, attrs, s.roundabout[rows].tolist(), t.segment_ids.tolist(),
                    nodes.tolist(), crossings)

    def intersection(self, k: int) -> dict[str, Any]:
        """OSRM's intersection where run ``k`` starts (k >= 1)."""
        return self.crossings.intersection(k - 1, self.t.ends.first[k])


@dataclass
class _Step:
    """A step being built: its runs ``first`` .. ``end`` - 1, maneuver and the intersections
    it passes."""

    kind: str
    turn: str | None
    first: int  # index of the step's first run in the leg
    location: list[float]
    before: float
    after: float
    attrs: Attrs
    end: int = 0  # one past its last run
    intersections: list[dict[str, Any]] = field(default_factory=list)
    exit: int | None = None


def _same_road(a: Attrs, b: Attrs) -> bool:
    return bool(a[0] or a[1]) and a[:2] == b[:2]


def _exits_passed(ctx: StepContext, leg: _Leg, step: _Step) -> int:
    """Nodes between consecutive roundabout runs where a road leaves the roundabout."""
    count = 0
    for node in leg.nodes[step.first:step.end - 1]:
        for road in ctx.junctions.roads(node):
            if not ctx.graph.segs.roundabout[road.row] and \
                    ctx.junctions.enterable(ctx.graph, road, ctx.avoid):
                count += 1
                break
    return count


def _group(ctx: StepContext, leg: _Leg) -> list[_Step]:
    """The leg's runs grouped into steps (before ``arrive``)."""
    t, ends = leg.t, leg.t.ends
    if not len(t.rows):
        return []
    steps = [_Step("depart", None, 0, t.start, 0.0, ends.b_out[0], leg.attrs[0], 1, [{
        "location": t.start, "bearings": [round(ends.b_out[0]) % 360], "entry": [True],
        "out": 0}])]
    for k in range(1, len(t.rows)):
        attrs, step = leg.attrs[k], steps[-1]
        turn = modifier(ends.b_in[k - 1], ends.b_out[k])
        on_roundabout = step.kind == "roundabout" and leg.roundabout[k]
        if on_roundabout or (turn == "straight" and attrs == step.attrs
                             and step.kind != "roundabout"):
            step.end = k + 1
            if leg.crossings.degree(k - 1) >= 3:
                step.intersections.append(leg.intersection(k))
            continue
        inter = leg.intersection(k)
        if leg.roundabout[k] and not leg.roundabout[k - 1]:
            steps.append(_Step("roundabout", turn, k, ends.first[k], ends.b_in[k - 1],
                               ends.b_out[k], attrs, k + 1, [inter]))
            continue
        if step.kind == "roundabout":
            kind = "exit roundabout"
            step.exit = _exits_passed(ctx, leg, step) + 1
            step.turn = modifier(step.before, ends.b_out[k])
            step.attrs = (attrs[0], attrs[1], *step.attrs[2:])
        elif turn == "uturn" or _same_road(attrs, step.attrs):
            kind = "continue"
        else:
            kind = "new name" if turn == "straight" else "turn"
        new = _Step(kind, turn, k, ends.first[k], ends.b_in[k - 1], ends.b_out[k], attrs,
                    k + 1, [inter])
        new.exit = step.exit if kind == "exit roundabout" else None
        steps.append(new)
    if steps[-1].kind == "roundabout":  # arriving on the roundabout
        steps[-1].exit = _exits_passed(ctx, leg, steps[-1]) + 1
        steps[-1].turn = modifier(steps[-1].before, ends.b_in[steps[-1].end - 1])
    return steps


def _render(ctx: StepContext, leg: _Leg, s: _Step, distance: float, duration: float
            ) -> dict[str, Any]:
    t = leg.t
    coords = t.coords[t.starts[s.first]:t.starts[s.end] + 1]
    maneuver: dict[str, Any] = {"type": s.kind, "location": s.location,
                                "bearing_before": round(s.before) % 360,
                                "bearing_after": round(s.after) % 360}
    if s.turn is not None:
        maneuver["modifier"] = s.turn
    if s.exit is not None:
        maneuver["exit"] = s.exit
    name, ref, lanes, limit, kph, road_class = s.attrs
    out: dict[str, Any] = {
        "distance": distance, "duration": duration,
        "weight": duration if ctx.cost is Cost.TIME else distance,
        "geometry": ctx.encode(coords), "name": name, "mode": "driving",
        "driving_side": ctx.driving_side, "maneuver": maneuver,
        "intersections": s.intersections,
        "segment_ids": leg.segment_ids[s.first:s.end],
        "lanes": lanes, "speed_limit_kph": limit, "speed_kph": kph, "road_class": road_class,
    }
    if ref:
        out["ref"] = ref
    return out


def _arrive(ctx: StepContext, t: Trace, name: str) -> dict[str, Any]:
    heading = t.ends.b_in[-1] if len(t.rows) else 0.0
    maneuver: dict[str, Any] = {"type": "arrive", "location": t.end,
                                "bearing_before": round(heading) % 360, "bearing_after": 0}
    snap = t.leg.end
    if len(t.rows) and snap.distance_m > ON_ROAD_M:
        maneuver["modifier"] = "right" if side_of(t.end, heading, snap.point) > 0 else "left"
    return {
        "distance": 0.0, "duration": 0.0, "weight": 0.0,
        "geometry": ctx.encode(np.array([t.end, t.end])),
        "name": name, "mode": "driving", "driving_side": ctx.driving_side,
        "maneuver": maneuver, "segment_ids": [],
        "intersections": [{"location": t.end, "bearings": [round(heading + 180.0) % 360],
                           "entry": [True], "in": 0}],
    }


def leg_steps(ctx: StepContext, t: Trace) -> list[dict[str, Any]]:
    """The OSRM steps of one leg, ending with ``arrive``."""
    leg = _Leg.of(ctx, t)
    steps = _group(ctx, leg)
    bounds = [s.first for s in steps] + [len(t.rows)]
    # Each step's distance and duration: numpy's sum over the step's pieces, for all at once.
    distance = np.add.reduceat(t.distance, bounds[:-1]).tolist() if steps else []
    duration = np.add.reduceat(t.duration, bounds[:-1]).tolist() if steps else []
    return [*(_render(ctx, leg, s, d, u) for s, d, u in zip(steps, distance, duration,
                                                            strict=True)),
            _arrive(ctx, t, leg.attrs[-1][0] if len(t.rows) else "")]
