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
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np

from app.routing.costs import Cost
from app.routing.geometry import side_of
from app.routing.graph import RoadGraph
from app.routing.junctions import Crossings, Junctions
from app.routing.native import kernel
from app.routing.trace import Trace

STRAIGHT_DEG = 30.0
SLIGHT_DEG = 60.0
PLAIN_DEG = 120.0
UTURN_DEG = 170.0
ON_ROAD_M = 0.5  # an end point this close to the road is on neither side


# OSRM's turn modifiers, indexed by :func:`_turn`'s code.
MODIFIERS = ("straight", "uturn", "slight right", "right", "sharp right", "slight left", "left",
             "sharp left")
STRAIGHT, UTURN = 0, 1
# Maneuvers that start a step, indexed by :func:`_maneuvers`' code (0: no new step).
KINDS = ("", "depart", "turn", "new name", "continue", "roundabout", "exit roundabout")
DEPART, TURN, NEW_NAME, CONTINUE, ROUNDABOUT, EXIT_ROUNDABOUT = range(1, 7)


@kernel("i8(f8, f8)")
def _turn(before: float, after: float) -> int:
    """The code in :data:`MODIFIERS` of OSRM's turn modifier from the bearing ``before`` to the
    bearing ``after`` a maneuver point."""
    delta = (after - before + 540.0) % 360.0 - 180.0  # -180..180, positive = clockwise
    size = abs(delta)
    if size <= STRAIGHT_DEG:
        return STRAIGHT
    if size >= UTURN_DEG:
        return UTURN
    grade = 2 if size <= SLIGHT_DEG else 3 if size <= PLAIN_DEG else 4
    return grade if delta > 0 else grade + 3


def modifier(before: float, after: float) -> str:
    """OSRM's turn modifier from the bearing before to the bearing after a maneuver point."""
    return MODIFIERS[_turn(before, after)]


@kernel("UniTuple(i8[:], 2)(f8[:], f8[:], b1[:], b1[:], b1[:], b1[:])")
def _maneuvers(b_in: np.ndarray, b_out: np.ndarray, same_attrs: np.ndarray,
               same_road: np.ndarray, unnamed: np.ndarray, roundabout: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Per run of a leg, the maneuver (:data:`KINDS`) that starts a step there, 0 where the
    run carries on the step before, and the turn (:data:`MODIFIERS`) from the run before.

    ``same_attrs[k]``: run k has the attributes of run k - 1 (name, ref, lanes, speed limit,
    speed, class), so it carries on that step when driven straight into; ``same_road[k]``:
    it has a name or ref, and run k - 1's (a new step there is a ``continue``); ``unnamed[k]``:
    neither run k nor run k - 1 has a name or ref (straight on, a ``continue``: OSRM's
    ``new name`` would announce a name that is not there). Comparing with the
    run before is comparing with the step's first run, since a step's runs all share its
    attributes; a roundabout step gathers the roundabout's runs whatever they are."""
    n = len(b_in)
    kind = np.zeros(n, np.int64)
    turn = np.zeros(n, np.int64)
    if n:
        kind[0] = DEPART
    current = DEPART
    for k in range(1, n):
        turn[k] = _turn(b_in[k - 1], b_out[k])
        if current == ROUNDABOUT:
            if roundabout[k]:
                continue
        elif turn[k] == STRAIGHT and same_attrs[k]:
            continue
        if roundabout[k] and not roundabout[k - 1]:
            kind[k] = ROUNDABOUT
        elif current == ROUNDABOUT:
            kind[k] = EXIT_ROUNDABOUT
        elif turn[k] == UTURN or same_road[k]:
            kind[k] = CONTINUE
        else:
            kind[k] = TURN if turn[k] != STRAIGHT else CONTINUE if unnamed[k] else NEW_NAME
        current = kind[k]
    return kind, turn


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
    """A leg's runs (their attributes as Python lists), and the roads at each joint: every
    lookup the grouping makes, read for the whole leg at once (a grid route has ~300 runs)."""

    t: Trace
    attrs: list[Attrs]
    roundabout: np.ndarray  # bool per run
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
        return _Leg(t, attrs, s.roundabout[rows], t.segment_ids.tolist(), nodes.tolist(),
                    crossings)

    def maneuvers(self) -> tuple[list[int], list[int], list[int]]:
        """The runs where steps start, their maneuvers and turns (:func:`_maneuvers`)."""
        attrs, ends = self.attrs, self.t.ends
        pairs = list(pairwise(attrs))
        same_attrs = [False, *(a == b for a, b in pairs)]
        same_road = [False, *(bool(b[0] or b[1]) and a[:2] == b[:2] for a, b in pairs)]
        unnamed = [False, *(not (a[0] or a[1] or b[0] or b[1]) for a, b in pairs)]
        kind, turn = _maneuvers(np.array(ends.b_in), np.array(ends.b_out),
                                np.array(same_attrs), np.array(same_road), np.array(unnamed),
                                self.roundabout)
        firsts = np.flatnonzero(kind)
        return firsts.tolist(), kind[firsts].tolist(), turn[firsts].tolist()

    def intersection(self, k: int) -> dict[str, Any]:
        """OSRM's intersection where run ``k`` starts (k >= 1)."""
        return self.crossings.intersection(k - 1, self.t.ends.first[k])

    def passed(self, first: int, end: int) -> list[dict[str, Any]]:
        """The intersections (three or more roads) inside a step of runs ``first`` .. ``end``
        - 1, after its maneuver point."""
        degree = self.crossings.degree
        return [self.intersection(k) for k in range(first + 1, end) if degree(k - 1) >= 3]


@dataclass
class _Step:
    """A step: its runs ``first`` .. ``end`` - 1, maneuver and the intersections it passes."""

    kind: str
    turn: str | None
    first: int  # index of the step's first run in the leg
    location: list[float]
    before: float
    after: float
    attrs: Attrs
    end: int  # one past its last run
    intersections: list[dict[str, Any]]
    exit: int | None = None


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
    """The leg's runs grouped into steps (before ``arrive``): where each starts and with which
    maneuver is :func:`_maneuvers`' decision; a roundabout step then takes its exit's number,
    name and turn from the step that leaves it."""
    t, ends = leg.t, leg.t.ends
    n = len(t.rows)
    if not n:
        return []
    firsts, kinds, turns = leg.maneuvers()
    steps = []
    for first, end, kind, turn in zip(firsts, [*firsts[1:], n], kinds, turns, strict=True):
        if kind == DEPART:
            steps.append(_Step("depart", None, 0, t.start, 0.0, ends.b_out[0], leg.attrs[0], end, [
                {"location": t.start, "bearings": [round(ends.b_out[0]) % 360], "entry": [True],
                 "out": 0}, *leg.passed(0, end)]))
            continue
        steps.append(_Step(KINDS[kind], MODIFIERS[turn], first, ends.first[first],
                           ends.b_in[first - 1], ends.b_out[first], leg.attrs[first], end,
                           [leg.intersection(first), *leg.passed(first, end)]))
    for step, leaving in pairwise(steps):
        if step.kind == "roundabout":  # ``leaving`` is its exit
            step.exit = leaving.exit = _exits_passed(ctx, leg, step) + 1
            step.turn = modifier(step.before, leaving.after)
            step.attrs = (leaving.attrs[0], leaving.attrs[1], *step.attrs[2:])
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
