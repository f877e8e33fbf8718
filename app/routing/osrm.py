"""Shape routes into an OSRM route-service response, so existing OSRM clients work unchanged.

Follows OSRM v5: ``code``, ``routes[]`` (``geometry`` per ``geometries``/``overview``,
``distance``, ``duration``, ``weight``, ``weight_name``, ``legs[]``) and ``waypoints[]``
(``hint``, ``distance``, ``name``, ``location``). Each leg has ``summary``, ``steps`` (when asked;
see :mod:`app.routing.steps`) and ``annotation`` (when asked): OSRM's per-coordinate-pair
arrays over the leg's full geometry (``distance``, ``duration``, ``speed``, ``weight``,
``datasources``) and ``nodes``, one id per coordinate (:func:`app.routing.trace.node_ids`).

Besides OSRM's fields, what a vehicle planner needs: each leg's ``segments`` (every segment
piece driven: ``id``, ``forward``, ``from_fraction``, ``to_fraction``, ``distance``,
``duration``), each step's ``segment_ids``, ``lanes`` (direction of travel),
``speed_limit_kph``, ``speed_kph`` and ``road_class``, and each waypoint's ``segment_id`` and
``fraction``.
"""

from __future__ import annotations

import base64
import struct
from collections.abc import Sequence
from typing import Any, TypeVar

import numpy as np

from app.errors import ResponseTooLargeError
from app.routing.budget import Budget
from app.routing.encoded_polyline import encode as encode_polyline
from app.routing.engine import Leg
from app.routing.graph import RoadGraph
from app.routing.junctions import junctions
from app.routing.options import RouteOptions
from app.routing.overview import simplify
from app.routing.settings import routing_settings
from app.routing.snap import Snap
from app.routing.steps import StepContext, leg_steps
from app.routing.trace import Trace, location, node_ids, trace

T = TypeVar("T")

DATASOURCE_NAMES = ["ugvmap"]  # annotation.metadata: every speed comes from the network


def encode(coords: np.ndarray | Sequence[Sequence[float]], geometries: str) -> Any:
    """A line as OSRM sends it: an encoded polyline (precision 5 or 6) or GeoJSON. GeoJSON
    coordinates stay a numpy array, which orjson writes from the array's memory (every answer
    is serialised with ``OPT_SERIALIZE_NUMPY``): turned into lists of Python floats first,
    a route's step and overview geometries cost a fifth of a city route's planning."""
    line = np.asarray(coords, np.float64)
    if geometries in ("polyline", "polyline6"):
        return encode_polyline(line, 6 if geometries == "polyline6" else 5)
    return {"type": "LineString", "coordinates": np.ascontiguousarray(line)}


def hint(snap: Snap, version: int) -> str:
    """An opaque OSRM-style waypoint hint (segment, fraction, graph version, base64url). Clients
    send hints back; they are accepted and not needed (a snap costs one indexed query)."""
    raw = struct.pack("<qdq", snap.segment_id, snap.fraction, version)
    return base64.urlsafe_b64encode(raw).decode("ascii").rstrip("=")


def waypoint(graph: RoadGraph, snap: Snap, hints: bool) -> dict[str, Any]:
    """An OSRM waypoint (``name``, ``location``, ``distance``, ``hint``), plus the segment id
    and fraction the point snapped to."""
    row = graph.row_of(snap.segment_id)
    assert row is not None
    out: dict[str, Any] = {
        "name": graph.segs.name[row] or "", "location": location(graph, snap),
        "distance": snap.distance_m, "segment_id": snap.segment_id, "fraction": snap.fraction,
    }
    if hints:
        out["hint"] = hint(snap, graph.version)
    return out


class Shaper:
    """Turns the routes of one request into the response dictionary."""

    def __init__(self, graph: RoadGraph, opts: RouteOptions, budget: Budget | None = None
                 ) -> None:
        self.graph, self.opts, self.budget = graph, opts, budget
        self.context = StepContext(
            graph, junctions(graph), opts.avoid, opts.cost,
            routing_settings().driving_side, self.encode) if opts.steps else None

    def encode(self, coords: np.ndarray | Sequence[Sequence[float]]) -> Any:
        """A line in the requested ``geometries``."""
        return encode(coords, self.opts.geometries)

    def _checked(self, item: T) -> T:
        """``item``, once the request's time budget (when it has one) is found not spent:
        shaping a 5,000-leg match alone took longer than its whole budget."""
        if self.budget is not None:
            self.budget.check()
        return item

    def _summary(self, t: Trace) -> str:
        length: dict[str, float] = {}
        for name, metres in zip(self.graph.segs.name[t.rows].tolist(), t.distance.tolist(),
                                strict=True):
            if name:
                length[name] = length.get(name, 0.0) + metres
        longest = sorted(length, key=length.__getitem__, reverse=True)[:2]
        return ", ".join(n for n in length if n in longest)

    def _annotation(self, t: Trace) -> dict[str, Any]:
        wanted, cost = self.opts.annotations, self.opts.cost
        distance: list[float] = []
        duration: list[float] = []
        for run in t.runs:
            pair_m = run.pair_m
            distance.extend(pair_m.tolist())
            duration.extend((pair_m / run.speed_ms).tolist())
        if not len(t.rows):
            distance, duration = [0.0], [0.0]
        out: dict[str, Any] = {}
        if "distance" in wanted:
            out["distance"] = distance
        if "duration" in wanted:
            out["duration"] = duration
        if "speed" in wanted:
            out["speed"] = [round(d / s, 1) if s > 0 else 0.0
                            for d, s in zip(distance, duration, strict=True)]
        if "weight" in wanted:
            out["weight"] = duration if cost.value == "time" else distance
        if "nodes" in wanted:
            out["nodes"] = node_ids(self.graph, t)
        if "datasources" in wanted:
            out["datasources"] = [0] * len(distance)
            out["metadata"] = {"datasource_names": DATASOURCE_NAMES}
        return out

    def _leg(self, t: Trace) -> dict[str, Any]:
        out: dict[str, Any] = {
            "distance": float(t.distance.sum()), "duration": float(t.duration.sum()),
            "weight": t.leg.weight, "summary": self._summary(t),
            "steps": leg_steps(self.context, t) if self.context is not None else [],
            "segments": [{"id": i, "forward": f, "from_fraction": a, "to_fraction": b,
                          "distance": d, "duration": s}
                         for i, f, a, b, d, s in zip(
                             t.segment_ids.tolist(), t.forward.tolist(), t.f_from.tolist(),
                             t.f_to.tolist(), t.distance.tolist(), t.duration.tolist(),
                             strict=True)],
        }
        if self.opts.annotations:
            out["annotation"] = self._annotation(t)
        return out

    def route(self, legs: Sequence[Leg]) -> dict[str, Any]:
        """One route of the response."""
        return self.route_of([trace(self.graph, leg) for leg in legs])

    def route_of(self, traces: Sequence[Trace]) -> dict[str, Any]:
        """One route of the response, from its legs' traces."""
        legs = [self._leg(self._checked(t)) for t in traces]
        route: dict[str, Any] = {
            "distance": sum(leg["distance"] for leg in legs),
            "duration": sum(leg["duration"] for leg in legs),
            "weight": sum(t.leg.weight for t in traces),
            "weight_name": "duration" if self.opts.cost.value == "time" else "distance",
            "legs": legs,
        }
        if self.opts.overview != "false":
            coords = np.concatenate([traces[0].coords, *(t.coords[1:] for t in traces[1:])])
            route["geometry"] = self.encode(simplify(coords) if self.opts.overview == "simplified"
                                            else coords)
        return route

    def waypoint(self, snap: Snap, waypoint_index: int) -> dict[str, Any]:
        """A route's waypoint: where the point snapped and its rank in the visiting order."""
        return {**waypoint(self.graph, snap, self.opts.generate_hints),
                "waypoint_index": waypoint_index}

    def routes(self, routes: Sequence[Sequence[Leg]]) -> list[dict[str, Any]]:
        """OSRM route objects, refused (``ResponseTooLarge``) over the output caps."""
        traces = [[trace(self.graph, self._checked(leg)) for leg in legs] for legs in routes]
        check_size(traces, self.opts)
        return [self.route_of(t) for t in traces]

    def response(self, routes: Sequence[Sequence[Leg]], snaps: Sequence[Snap],
                 order: Sequence[int] | None = None) -> dict[str, Any]:
        """The whole OSRM route-service response: ``routes[0]`` the best, then alternatives."""
        body: dict[str, Any] = {"code": "Ok", "routes": self.routes(routes)}
        if not self.opts.skip_waypoints:
            visit = list(order) if order is not None else list(range(len(snaps)))
            rank = {i: k for k, i in enumerate(visit)}
            body["waypoints"] = [self.waypoint(s, rank[s.index]) for s in snaps]
        return body


def check_size(routes: Sequence[Sequence[Trace]], opts: RouteOptions) -> None:
    """Refuse an answer over ``max_response_coordinates`` before encoding it: overview and step
    geometries each carry every coordinate once."""
    per_copy = sum(len(t.coords) for legs in routes for t in legs)
    copies = (opts.overview != "false") + opts.steps
    most = routing_settings().max_response_coordinates
    if per_copy * max(copies, 1) > most:
        raise ResponseTooLargeError(
            f"the answer would hold {per_copy * max(copies, 1)} coordinates; at most {most} "
            "(UGVMAP_ROUTING_MAX_RESPONSE_COORDINATES): ask for overview=false, steps=false, "
            "fewer alternatives or a shorter route")
