"""``route`` with ``offroad=true``: a request end to end (snap or not, the cost surface, the
legs, the answer), which :func:`app.routing.planner.plan_route` (our URL and the CLI) hands
over to.

When every point is within the snap radius of a road the answer is the road route's, as
without ``offroad`` (with ``z`` and grade in ``format=waypoints``). Otherwise each leg is
planned by :func:`app.terrain.offroad.plan_leg` and the answer keeps OSRM's shape, with the
off-road parts marked: each leg and step says ``offroad``, off-road steps carry their
``slope_profile``, and the route's ``parts`` give the ranges of its geometry's coordinates
that are off road or on the road.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from sqlalchemy import Connection

from app.db.session import get_engine
from app.errors import NoSegmentError, ResponseTooLargeError
from app.routing.geometry import local_frame
from app.routing.graph import RoadGraph
from app.routing.options import RouteOptions
from app.routing.osrm import encode
from app.routing.reads import Reads
from app.routing.settings import routing_settings
from app.routing.snap import network_graph, snap_on
from app.routing.waypoints import frame_doc
from app.terrain.heights import heights_at
from app.terrain.offroad import Part, check_point, plan_leg, slope_profile
from app.terrain.roads import roads_over
from app.terrain.surface import Surface, surface_for


def plan_offroad_route(reads: Reads, network: str, points: list[tuple[float, float]],
                       opts: RouteOptions, graph_at: Callable[[int, int], RoadGraph]
                       ) -> dict[str, Any] | None:
    """The route through ``points`` allowed to leave the road (module docstring); None when
    every point is within the snap radius of a road (the road route is the answer)."""
    off = opts.offroad
    assert off is not None
    graph = network_graph(reads, network, graph_at)
    on_road = [_snaps(graph, p, opts, i) for i, p in enumerate(points)]
    if all(on_road):
        return None
    with get_engine().connect() as conn:
        surface = surface_for(conn, off.elevation, off.settings, off.surface, off.forbid)
        roads = roads_over(graph, surface, opts.avoid, 3.6 / off.settings.speeds[0][1])
        cells = [check_point(surface, roads, i, p, on_road[i], off.elevation, off.settings,
                             opts.vehicle.name) for i, p in enumerate(points)]
        legs = [plan_leg(surface, roads, cells[i], cells[i + 1], points[i], points[i + 1])
                for i in range(len(points) - 1)]
        if opts.format == "waypoints":
            return {"code": "Ok", **offroad_waypoints(conn, off.elevation, legs,
                                                      opts.spacing_m),
                    "order": list(range(len(points)))}
    return _response(surface, legs, points, opts)


def _snaps(graph: RoadGraph, point: tuple[float, float], opts: RouteOptions, i: int) -> bool:
    """Whether point ``i`` is within its snap radius of a road its vehicle may drive."""
    try:
        snap_on(graph, [point], [opts.point(i)], opts.avoid)
    except NoSegmentError:
        return False
    return True


def _step(surface: Surface, part: Part, geometries: str) -> dict[str, Any]:
    step: dict[str, Any] = {
        "mode": "offroad" if part.offroad else "driving", "offroad": part.offroad,
        "distance": round(part.metres, 1), "duration": round(part.seconds, 1),
        "weight": round(part.seconds, 1), "geometry": encode(part.coords, geometries)}
    if part.offroad:
        profile = slope_profile(surface, part)
        step["slope_profile"] = profile
        step["max_grade_pct"] = max((abs(g) for _, _, g in profile), default=0.0)
    else:
        step["segments"] = part.segments
    return step


def _response(surface: Surface, legs: list[list[Part]], points: list[tuple[float, float]],
              opts: RouteOptions) -> dict[str, Any]:
    coords: list[tuple[float, float]] = []
    ranges: list[dict[str, Any]] = []
    out_legs: list[dict[str, Any]] = []
    for leg in legs:
        for part in leg:
            start = max(0, len(coords) - 1)
            coords.extend(part.coords[1:] if coords else part.coords)
            ranges.append({"offroad": part.offroad, "from": start, "to": len(coords) - 1})
        out_legs.append({
            "distance": round(sum(p.metres for p in leg), 1),
            "duration": round(sum(p.seconds for p in leg), 1),
            "weight": round(sum(p.seconds for p in leg), 1),
            "offroad": any(p.offroad for p in leg), "summary": "",
            "steps": [_step(surface, p, opts.geometries) for p in leg] if opts.steps else []})
    duration = sum(float(leg["duration"]) for leg in out_legs)
    return {"code": "Ok", "routes": [{
        "distance": round(sum(float(leg["distance"]) for leg in out_legs), 1),
        "duration": round(duration, 1), "weight": round(duration, 1),
        "weight_name": "offroad_time", "geometry": encode(coords, opts.geometries),
        "parts": ranges, "legs": out_legs}],
        "waypoints": [{"location": list(p), "name": "", "offroad": True, "waypoint_index": i}
                      for i, p in enumerate(points)]}


def add_heights(conn: Connection, layer: str, points: list[dict[str, Any]]) -> None:
    """Give dense waypoints ``z`` (the layer's height, null where it has none) and
    ``grade_pct`` (towards the next point; the last repeats the one before)."""
    z = heights_at(conn, layer, [(p["lon"], p["lat"]) for p in points])
    for k, p in enumerate(points):
        height = z[k]
        p["z"] = None if height is None else round(height, 3)
    for k, p in enumerate(points):
        j = min(k, len(points) - 2)
        here, there = (z[j], z[j + 1]) if j >= 0 else (None, None)
        run = points[j + 1]["s"] - points[j]["s"] if j >= 0 else 0.0
        p["grade_pct"] = (None if here is None or there is None
                          else round((there - here) / run * 100, 2) if run > 0 else 0.0)


def offroad_waypoints(conn: Connection, layer: str, legs: list[list[Part]],
                      spacing_m: float) -> dict[str, Any]:
    """Points every ``spacing_m`` along the route in a local metric frame at its start, as
    ``format=waypoints`` gives for roads, with ``offroad``, the segment (on the road),
    ``z`` and ``grade_pct``."""
    parts = [p for leg in legs for p in leg]
    lonlat = np.array([c for p in parts for c in p.coords])
    # Per vertex of the joined line: its part, and (on the road) the segment of the edge
    # leaving it; consecutive parts share their joining coordinate.
    owner = np.concatenate([[k] * (len(p.coords) - 1) + [k] for k, p in enumerate(parts)])
    segment: list[int | None] = []
    for p in parts:
        edges: list[int | None] = (list(p.edge_segments) if p.edge_segments
                                   else [None] * (len(p.coords) - 1))
        segment += [*edges, None]
    frame = local_frame(*lonlat[0])
    x, y = (np.asarray(v) for v in frame.transform(lonlat[:, 0], lonlat[:, 1]))
    along = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
    count, most = int(along[-1] // spacing_m) + 2, routing_settings().max_waypoints
    if count > most:
        raise ResponseTooLargeError(
            f"{along[-1]:.0f} m every {spacing_m:g} m is {count} waypoints; at most {most} "
            "(UGVMAP_ROUTING_MAX_WAYPOINTS): ask for a larger spacing")
    stations = np.append(np.arange(0.0, along[-1], spacing_m), along[-1])
    px, py = np.interp(stations, along, x), np.interp(stations, along, y)
    vertex = np.clip(np.searchsorted(along, stations, side="right") - 1, 0, len(owner) - 1)
    lon, lat = frame.transform(px, py, direction="INVERSE")
    points = []
    for k, st in enumerate(stations):
        part = parts[int(owner[vertex[k]])]
        points.append({
            "x": round(float(px[k]), 3), "y": round(float(py[k]), 3),
            "lon": round(float(lon[k]), 8), "lat": round(float(lat[k]), 8),
            "s": round(float(st), 3), "offroad": part.offroad,
            "segment_id": segment[int(vertex[k])]})
    add_heights(conn, layer, points)
    return {"frame": frame_doc(lonlat[0]), "spacing_m": spacing_m,
            "length_m": float(along[-1]), "points": points}
