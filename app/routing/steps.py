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
from app.routing.junctions import Junctions
from app.routing.trace import Run, Trace

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

    def roundabout(self, run: Run) -> bool:
        """Is the run on a roundabout (OSM ``junction=roundabout|circular``)?"""
        return bool(self.graph.segs.roundabout[run.piece.row])

    def attrs(self, t: Trace) -> list[dict[str, Any]]:
        """Per-step attributes of each run of a leg (a new step starts where any of them
        changes), read for all runs at once."""
        s = self.graph.segs
        rows = np.array([p.row for p in t.pieces], np.int64)
        lanes = np.where(t.forward, s.lanes_forward[rows], s.lanes_backward[rows])
        return [{"name": name or "", "ref": ref or "", "lanes": n,
                 "speed_limit_kph": None if limit != limit else limit, "speed_kph": kph,
                 "road_class": cls}
                for name, ref, n, limit, kph, cls in zip(
                    s.name[rows].tolist(), s.ref[rows].tolist(), lanes.tolist(),
                    s.speed_limit[rows].tolist(), self.graph.speed_kph[rows].tolist(),
                    s.road_class[rows].tolist(), strict=True)]

    def node_after(self, run: Run) -> int:
        """Graph node index where a run ends at a segment end."""
        row = run.piece.row
        return int(self.graph.v[row] if run.piece.f_to == 1.0 else self.graph.u[row])


@dataclass
class _Step:
    """A step being built: its runs, maneuver and the intersections it passes."""

    kind: str
    turn: str | None
    first: int  # index of the step's first run in the leg
    location: list[float]
    before: float
    after: float
    attrs: dict[str, Any]
    runs: list[Run] = field(default_factory=list)
    intersections: list[dict[str, Any]] = field(default_factory=list)
    exit: int | None = None


def _same_road(a: dict[str, Any], b: dict[str, Any]) -> bool:
    return bool(a["name"] or a["ref"]) and (a["name"], a["ref"]) == (b["name"], b["ref"])


def _exits_passed(ctx: StepContext, runs: list[Run]) -> int:
    """Nodes between consecutive roundabout runs where a road leaves the roundabout."""
    count = 0
    for prev in runs[:-1]:
        node = ctx.node_after(prev)
        for road in ctx.junctions.roads(node):
            if not ctx.graph.segs.roundabout[road.row] and \
                    ctx.junctions.enterable(ctx.graph, road, ctx.avoid):
                count += 1
                break
    return count


def _intersection(ctx: StepContext, prev: Run, run: Run) -> dict[str, Any]:
    node = ctx.node_after(prev)
    return ctx.junctions.intersection(ctx.graph, node, run.coords[0].tolist(),
                                      (prev.piece.row, prev.forward),
                                      (run.piece.row, not run.forward), ctx.avoid)


def _group(ctx: StepContext, t: Trace, all_attrs: list[dict[str, Any]]) -> list[_Step]:
    """The leg's runs grouped into steps (before ``arrive``)."""
    steps: list[_Step] = []
    prev: Run | None = None
    for k, (run, attrs) in enumerate(zip(t.runs, all_attrs, strict=True)):
        if prev is None:
            steps.append(_Step("depart", None, 0, t.start, 0.0, run.b_out, attrs, [run], [{
                "location": t.start, "bearings": [round(run.b_out) % 360], "entry": [True],
                "out": 0}]))
            prev = run
            continue
        step = steps[-1]
        turn = modifier(prev.b_in, run.b_out)
        on_roundabout = step.kind == "roundabout" and ctx.roundabout(run)
        if on_roundabout or (turn == "straight" and attrs == step.attrs
                             and step.kind != "roundabout"):
            step.runs.append(run)
            if ctx.junctions.degree(ctx.node_after(prev)) >= 3:
                step.intersections.append(_intersection(ctx, prev, run))
            prev = run
            continue
        inter = _intersection(ctx, prev, run)
        if ctx.roundabout(run) and not ctx.roundabout(prev):
            steps.append(_Step("roundabout", turn, k, run.coords[0].tolist(), prev.b_in,
                               run.b_out, attrs, [run], [inter]))
        else:
            if step.kind == "roundabout":
                kind = "exit roundabout"
                step.exit = _exits_passed(ctx, step.runs) + 1
                step.turn = modifier(step.before, run.b_out)
                step.attrs = {**step.attrs, "name": attrs["name"], "ref": attrs["ref"]}
            elif turn == "uturn" or _same_road(attrs, step.attrs):
                kind = "continue"
            else:
                kind = "new name" if turn == "straight" else "turn"
            new = _Step(kind, turn, k, run.coords[0].tolist(), prev.b_in, run.b_out, attrs,
                        [run], [inter])
            new.exit = step.exit if kind == "exit roundabout" else None
            steps.append(new)
        prev = run
    if steps and steps[-1].kind == "roundabout":  # arriving on the roundabout
        steps[-1].exit = _exits_passed(ctx, steps[-1].runs) + 1
        steps[-1].turn = modifier(steps[-1].before, steps[-1].runs[-1].b_in)
    return steps


def _render(ctx: StepContext, t: Trace, s: _Step) -> dict[str, Any]:
    last = s.first + len(s.runs)
    coords = t.coords[t.starts[s.first]:t.starts[last] + 1]
    maneuver: dict[str, Any] = {"type": s.kind, "location": s.location,
                                "bearing_before": round(s.before) % 360,
                                "bearing_after": round(s.after) % 360}
    if s.turn is not None:
        maneuver["modifier"] = s.turn
    if s.exit is not None:
        maneuver["exit"] = s.exit
    distance = float(t.distance[s.first:last].sum())
    duration = float(t.duration[s.first:last].sum())
    out: dict[str, Any] = {
        "distance": distance, "duration": duration,
        "weight": duration if ctx.cost is Cost.TIME else distance,
        "geometry": ctx.encode(coords), "name": s.attrs["name"], "mode": "driving",
        "driving_side": ctx.driving_side, "maneuver": maneuver,
        "intersections": s.intersections,
        "segment_ids": [r.segment_id for r in s.runs],
        **{k: v for k, v in s.attrs.items() if k not in ("name", "ref")},
    }
    if s.attrs["ref"]:
        out["ref"] = s.attrs["ref"]
    return out


def _arrive(ctx: StepContext, t: Trace, name: str) -> dict[str, Any]:
    last = t.runs[-1] if t.runs else None
    heading = last.b_in if last is not None else 0.0
    maneuver: dict[str, Any] = {"type": "arrive", "location": t.end,
                                "bearing_before": round(heading) % 360, "bearing_after": 0}
    snap = t.leg.end
    if last is not None and snap.distance_m > ON_ROAD_M:
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
    attrs = ctx.attrs(t)
    return [*(_render(ctx, t, s) for s in _group(ctx, t, attrs)),
            _arrive(ctx, t, attrs[-1]["name"] if attrs else "")]
