"""Dense waypoints every N metres along a route, in a local metric frame.

What a vehicle's tracker consumes: points ``x`` (east) / ``y`` (north) in metres in an
azimuthal equidistant frame centred on the route's first point (see
:func:`app.routing.geometry.local_frame`), with lon/lat, the segment, lanes and speed limit
in force at each point.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from app.errors import ResponseTooLargeError
from app.routing.engine import Leg
from app.routing.geometry import local_frame
from app.routing.graph import RoadGraph
from app.routing.settings import routing_settings
from app.routing.trace import location, run_of


def dense_waypoints(graph: RoadGraph, legs: list[Leg], spacing_m: float) -> dict[str, Any]:
    """Points every ``spacing_m`` along the route (plus its end), with per-point attributes;
    refused (422 ``ResponseTooLarge``) when that is more than ``max_waypoints`` points."""
    rows, xs, ys = [], [], []
    frame = None
    for leg in legs:
        for p in leg.pieces:
            if p.f_from == p.f_to:
                continue
            pc = np.array(run_of(graph, p).coords)
            if frame is None:
                frame = local_frame(*pc[0])
            x, y = frame.transform(pc[:, 0], pc[:, 1])
            rows.extend([(p.row, p.f_to >= p.f_from)] * (len(pc) - 1))
            xs.append(np.asarray(x))
            ys.append(np.asarray(y))
    if frame is None:  # start and end coincide
        start = location(graph, legs[0].start)
        return {"frame": frame_doc(start), "spacing_m": spacing_m, "points": []}
    # Each piece contributes its edges; consecutive pieces share their joining vertex.
    x = np.concatenate([xs[0][:1], *[a[1:] for a in xs]])
    y = np.concatenate([ys[0][:1], *[a[1:] for a in ys]])
    edge_rows = np.array(rows, dtype=np.int64)
    edge_len = np.hypot(np.diff(x), np.diff(y))
    along = np.concatenate([[0.0], np.cumsum(edge_len)])
    count, most = int(along[-1] // spacing_m) + 2, routing_settings().max_waypoints
    if count > most:
        raise ResponseTooLargeError(
            f"{along[-1]:.0f} m every {spacing_m:g} m is {count} waypoints; at most {most} "
            "(UGVMAP_ROUTING_MAX_WAYPOINTS): ask for a larger spacing")
    stations = np.arange(0.0, along[-1], spacing_m)
    stations = np.append(stations, along[-1])
    px, py = np.interp(stations, along, x), np.interp(stations, along, y)
    edge = np.clip(np.searchsorted(along, stations, side="right") - 1, 0, len(edge_rows) - 1)
    lon, lat = frame.transform(px, py, direction="INVERSE")
    s, g = graph.segs, graph
    origin = frame.transform(x[0], y[0], direction="INVERSE")
    points = []
    for k, st in enumerate(stations):
        r, forward = int(edge_rows[edge[k], 0]), bool(edge_rows[edge[k], 1])
        limit = s.speed_limit[r]
        points.append({
            "x": round(float(px[k]), 3), "y": round(float(py[k]), 3),
            "lon": round(float(lon[k]), 8), "lat": round(float(lat[k]), 8),
            "s": round(float(st), 3), "segment_id": int(s.ids[r]),
            "speed_limit_kph": None if limit != limit else float(limit),
            "speed_kph": float(g.speed_kph[r]),
            "lanes": int(s.lanes_forward[r] if forward else s.lanes_backward[r]),
        })
    return {"frame": frame_doc(origin), "spacing_m": spacing_m,
            "length_m": float(along[-1]), "points": points}


def frame_doc(origin: Any) -> dict[str, Any]:
    """The ``frame`` of dense waypoints: the aeqd frame at ``origin`` (lon, lat)."""
    lon0, lat0 = float(origin[0]), float(origin[1])
    return {"type": "aeqd", "origin": [lon0, lat0], "axes": ["east", "north"], "units": "m",
            "proj": f"+proj=aeqd +lat_0={lat0} +lon_0={lon0} +ellps=WGS84 +units=m"}
