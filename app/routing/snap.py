"""Snap request points to road segments: the nearest that fits each point's options.

Candidates come from the graph itself (:mod:`app.routing.nearby`: an in-memory index, every
segment within the point's radius measured in the point's local metric frame), on the graph
version the request's one database read names (:meth:`app.routing.reads.Reads.network`), so
a snap never misses or keeps a segment an edit committed before the request changed.

OSRM's per-point options act on the choice (:func:`choose`): a candidate must lie within the
point's radius, and each direction along it must fit the point's bearing (``value ± range``)
and approach side (``curb``: the point on the driving side). A candidate with no direction
left is skipped for the next nearest; the directions kept travel with the snap, so the route
leaves and reaches the point only in them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from app.errors import NoSegmentError
from app.routing import params
from app.routing.geometry import bearing_at, point_at, side_of
from app.routing.graph import RoadGraph
from app.routing.nearby import Hits, within
from app.routing.options import PointOptions
from app.routing.reads import Reads
from app.routing.settings import routing_settings

ON_ROAD_M = 0.5  # a point this close to its segment is on neither side (any approach)


@dataclass(frozen=True)
class Snap:
    """Where a request point meets the network, and the directions it may be driven there."""

    index: int  # position of the point in the request
    point: tuple[float, float]  # as given, lon/lat
    segment_id: int
    fraction: float  # along the segment's geometry, metric
    distance_m: float  # from the point to the segment
    forward: bool = True  # may be driven along the segment's geometry at this point
    backward: bool = True  # ... and against it

    @property
    def restricted(self) -> bool:
        """True when the point's options forbid one of the directions the segment allows."""
        return not (self.forward and self.backward)


def _directions(graph: RoadGraph, row: int, fraction: float, distance_m: float,
                point: tuple[float, float], opts: PointOptions) -> tuple[bool, bool]:
    """(forward, backward): the directions along the candidate the point's bearing and approach
    allow (one-way rules are the engine's, applied with them)."""
    forward = backward = True
    if opts.bearing is None and opts.approach == "unrestricted":
        return forward, backward
    coords, fracs = graph.line(row)
    heading = bearing_at(coords, fracs, fraction)
    if opts.bearing is not None:
        value, spread = opts.bearing

        def fits(h: float) -> bool:
            return abs((h - value + 180.0) % 360.0 - 180.0) <= spread

        forward, backward = forward and fits(heading), backward and fits(heading + 180.0)
    if opts.approach != "unrestricted" and distance_m > ON_ROAD_M:
        on_right = side_of(point_at(coords, fracs, fraction), heading, point) > 0
        curb_right = routing_settings().driving_side == "right"
        # Driving along the geometry, the curb is on the driving side; against it, opposite.
        along_is_curb = on_right == curb_right
        want_curb = opts.approach == "curb"
        forward = forward and along_is_curb == want_curb
        backward = backward and along_is_curb != want_curb
    return forward, backward


def fitting(graph: RoadGraph, near: Hits, i: int, point: tuple[float, float],
            opts: PointOptions) -> Iterator[Snap]:
    """The candidates within the point's radius that leave a direction to drive, nearest
    first, as snaps of input point ``i``."""
    for row, distance, fraction in zip(near.row.tolist(), near.distance_m.tolist(),
                                       near.fraction.tolist(), strict=True):
        if not distance <= opts.radius_m:  # NaN: off the globe
            continue
        forward, backward = _directions(graph, row, fraction, distance, point, opts)
        way = int(graph.segs.oneway[row])
        if (forward and way >= 0) or (backward and way <= 0):
            yield Snap(i, point, int(graph.segs.ids[row]), fraction, distance, forward,
                       backward)


def no_segment(graph: RoadGraph, i: int, point: tuple[float, float], near: Hits,
               opts: PointOptions, avoid: frozenset[str]) -> NoSegmentError:
    """The error naming the point and why none of its candidates would do."""
    where = f"{params.point(i)} ({point[0]:.6f},{point[1]:.6f})"
    valid = near.distance_m[np.isfinite(near.distance_m)]
    if len(valid):
        return NoSegmentError(f"{where}: no road within {opts.radius_m:g} m can be driven in a "
                              "direction its bearing and approach allow")
    if len(near):
        ids = ", ".join(str(int(graph.segs.ids[r])) for r in near.row[:16])
        return NoSegmentError(f"{where}: the nearest segments ({ids}) have coordinates outside "
                              "lon -180..180, lat -90..90; fix the network (ugvmap network "
                              "validate)")
    most = routing_settings().max_snap_radius_m
    wider = within(graph, np.array([point]), np.array([most]), avoid)
    found = wider.distance_m[np.isfinite(wider.distance_m)]
    nearest = (f"the nearest road is {found[0]:.1f} m away" if len(found)
               else f"no road within {most:g} m")
    return NoSegmentError(f"{where} is farther than {opts.radius_m:g} m from any road: "
                          f"{nearest}{_left_out_nearby(graph, point, opts.radius_m, avoid)}")


def _left_out_nearby(graph: RoadGraph, point: tuple[float, float], radius_m: float,
                     avoid: frozenset[str]) -> str:
    """Why a point on a footway is "farther than any road" for a car: the nearest way within
    the radius whose class the request leaves out, said so ("" when there is none)."""
    if not avoid:
        return ""
    near = within(graph, np.array([point]), np.array([radius_m]))
    hit = np.flatnonzero(np.isfinite(near.distance_m))
    if not len(hit):
        return ""
    row, metres = int(near.row[hit[0]]), float(near.distance_m[hit[0]])
    return (f"; the {graph.segs.road_class[row]} {metres:.1f} m away is not driven (the vehicle "
            "profile or avoid= leaves it out)")


def network_graph(reads: Reads, network: str, graph_at: Callable[[int, int], RoadGraph]
                  ) -> RoadGraph:
    """The network's graph holding every edit committed before this request (404 for an
    unknown network); ``graph_at(network_id, version)`` waits for the version read."""
    return graph_at(*reads.network(network))


def snap_on(graph: RoadGraph, points: Sequence[tuple[float, float]],
            opts: Sequence[PointOptions], avoid: frozenset[str]) -> list[Snap]:
    """Snap every point on ``graph``; ``NoSegment`` naming the first point that cannot."""
    hits = within(graph, np.array(points, np.float64).reshape(-1, 2),
                  np.array([o.radius_m for o in opts]), avoid)
    snaps = []
    for i, point in enumerate(points):
        near = hits.of(i)
        snap = next(fitting(graph, near, i, point, opts[i]), None)
        if snap is None:
            raise no_segment(graph, i, point, near, opts[i], avoid)
        snaps.append(snap)
    return snaps


def snap_points(reads: Reads, network: str, points: Sequence[tuple[float, float]],
                opts: Sequence[PointOptions], avoid: frozenset[str],
                graph_at: Callable[[int, int], RoadGraph]) -> tuple[RoadGraph, list[Snap]]:
    """The current graph of ``network`` and every point snapped on it."""
    graph = network_graph(reads, network, graph_at)
    return graph, snap_on(graph, points, opts, avoid)
