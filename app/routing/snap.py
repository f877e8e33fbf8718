"""Snap request points to road segments: PostGIS finds candidates, the graph picks one.

The KNN operator ``<->`` walks the GiST index for a few candidates per point (in degrees);
they are re-ranked by true (geography) distance, and the projection fraction is computed in the
point's UTM zone so that it is proportional to ground distance along the segment. The same
statement reads the network's version, which the caller uses to make sure the in-memory graph
already contains every committed edit.

Why two statements: a KNN search filtered by ``network_id`` is only planned as an index walk
when the planner believes the network is large; with fresh or small tables it estimates a few
rows and sorts the whole network by distance instead (8-36 ms rather than 0.3 ms). The first
statement therefore takes the nearest segments of *any* network (a plan with no alternative)
and filters afterwards; only points left without a candidate (another network or avoided
classes all around them, or none that fits the point's bearing and approach) are retried with
the filtered search.

OSRM's per-point options act on the choice (:func:`choose`): a candidate must lie within the
point's radius, and each direction along it must fit the point's bearing (``value ± range``)
and approach side (``curb``: the point on the driving side). A candidate with no direction
left is skipped for the next nearest; the directions kept travel with the snap, so the route
leaves and reaches the point only in them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from sqlalchemy import Connection, text

from app.errors import NoSegmentError, NotFoundError
from app.grid import utm_epsg
from app.routing.geometry import bearing_at, point_at, side_of
from app.routing.graph import RoadGraph
from app.routing.options import PointOptions
from app.routing.settings import routing_settings

KNN_NEAREST = 16  # unfiltered candidates per point (fast statement)
KNN_CANDIDATES = 8  # network candidates per point (fallback statement)
KNN_FILTERED = 64  # ... when the nearest do not fit a point's bearing or approach
ON_ROAD_M = 0.5  # a point this close to its segment is on neither side (any approach)

_SNAP = """
WITH net AS (SELECT id, version FROM networks WHERE name = :name),
pts AS (
    SELECT t.ord, ST_SetSRID(ST_MakePoint(t.lon, t.lat), 4326) AS g, t.utm
      FROM unnest(CAST(:lons AS float8[]), CAST(:lats AS float8[]), CAST(:utms AS int[]))
           WITH ORDINALITY AS t(lon, lat, utm, ord))
SELECT net.id, net.version, p.ord, c.id,
       CASE WHEN c.on_earth THEN ST_LineLocatePoint(ST_Transform(c.geom, p.utm),
                                                    ST_Transform(p.g, p.utm)) END,
       CASE WHEN c.on_earth THEN ST_Distance(c.geom::geography, p.g::geography) END
  FROM net CROSS JOIN pts p
  LEFT JOIN LATERAL ({candidates}) c
    ON c.network_id = net.id AND NOT (c.road_class = ANY(CAST(:avoid AS text[])))
"""
# A segment with coordinates off the globe (a bad import) cannot be projected: it is flagged
# instead of failing the whole statement.
_ON_EARTH = ("ST_XMin(s.geom) >= -180 AND ST_XMax(s.geom) <= 180 AND ST_YMin(s.geom) >= -90 "
             "AND ST_YMax(s.geom) <= 90 AS on_earth")
NEAREST_SQL = text(_SNAP.format(candidates=f"""
      SELECT s.id, s.geom, s.network_id, s.road_class, {_ON_EARTH} FROM road_segments s
       ORDER BY s.geom <-> p.g LIMIT {KNN_NEAREST}"""))
FILTERED_SQL = text(_SNAP.format(candidates=f"""
      SELECT s.id, s.geom, s.network_id, s.road_class, {_ON_EARTH} FROM road_segments s
       WHERE s.network_id = net.id AND NOT (s.road_class = ANY(CAST(:avoid AS text[])))
       ORDER BY s.geom <-> p.g LIMIT :k"""))


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


@dataclass(frozen=True)
class Candidate:
    """One segment near a point: ground distance and fraction, or ``None`` when the segment's
    coordinates are off the globe."""

    distance_m: float | None
    segment_id: int
    fraction: float | None

    def key(self) -> tuple:
        """Nearest first; on a tie (a point exactly at a junction, which may also lie under a
        bridge) a segment that ends there, then the lowest id for determinism."""
        d = self.distance_m if self.distance_m is not None else float("inf")
        return d, 0 if self.fraction in (0.0, 1.0) else 1, self.segment_id


@dataclass(frozen=True)
class Candidates:
    """Every request point's candidates, with the network version the statement read."""

    network_id: int
    version: int
    near: list[list[Candidate]]  # per point, nearest first


def _query(conn: Connection, sql, network: str, points: Sequence[tuple[float, float]],
           avoid: frozenset[str], k: int = KNN_CANDIDATES
           ) -> tuple[tuple[int, int] | None, list[list[Candidate]]]:
    """((network id, version) or None if unknown, per point candidates nearest first)."""
    rows = conn.execute(sql, {
        "name": network, "lons": [p[0] for p in points], "lats": [p[1] for p in points],
        "utms": [utm_epsg(*p) for p in points], "avoid": sorted(avoid), "k": k,
    }).all()
    near: list[list[Candidate]] = [[] for _ in points]
    if not rows:
        return None, near
    for row in rows:
        if row[3] is not None:
            near[row[2] - 1].append(Candidate(row[5], int(row[3]), row[4]))
    for found in near:
        found.sort(key=Candidate.key)
    return (int(rows[0][0]), int(rows[0][1])), near


def candidates(conn: Connection, network: str, points: Sequence[tuple[float, float]],
               avoid: frozenset[str] = frozenset()) -> Candidates:
    """The nearest segments of ``network`` to every point; 404 for an unknown network."""
    net, near = _query(conn, NEAREST_SQL, network, points, avoid)
    if net is None:
        raise NotFoundError(f"network {network!r} does not exist")
    missing = [i for i, found in enumerate(near) if not found]
    if missing:
        _, more = _query(conn, FILTERED_SQL, network, [points[i] for i in missing], avoid)
        for i, found in zip(missing, more, strict=True):
            near[i] = found
    return Candidates(net[0], net[1], near)


def _directions(graph: RoadGraph, row: int, c: Candidate, point: tuple[float, float],
                opts: PointOptions) -> tuple[bool, bool]:
    """(forward, backward): the directions along the candidate the point's bearing and approach
    allow (one-way rules are the engine's, applied with them)."""
    assert c.fraction is not None
    forward = backward = True
    if opts.bearing is None and opts.approach == "unrestricted":
        return forward, backward
    coords, fracs = graph.line(row)
    heading = bearing_at(coords, fracs, c.fraction)
    if opts.bearing is not None:
        value, spread = opts.bearing

        def fits(h: float) -> bool:
            return abs((h - value + 180.0) % 360.0 - 180.0) <= spread

        forward, backward = forward and fits(heading), backward and fits(heading + 180.0)
    if opts.approach != "unrestricted" and c.distance_m is not None \
            and c.distance_m > ON_ROAD_M:
        on_right = side_of(point_at(coords, fracs, c.fraction), heading, point) > 0
        curb_right = routing_settings().driving_side == "right"
        # Driving along the geometry, the curb is on the driving side; against it, opposite.
        along_is_curb = on_right == curb_right
        want_curb = opts.approach == "curb"
        forward = forward and along_is_curb == want_curb
        backward = backward and along_is_curb != want_curb
    return forward, backward


def choose(graph: RoadGraph, near: Sequence[Candidate], i: int, point: tuple[float, float],
           opts: PointOptions) -> Snap | None:
    """The nearest candidate within the point's radius that leaves a direction to drive."""
    for c in near:
        if c.distance_m is None or c.fraction is None or c.distance_m > opts.radius_m:
            continue
        row = graph.row_of(c.segment_id)
        if row is None:  # committed after the version we route on
            continue
        forward, backward = _directions(graph, row, c, point, opts)
        way = int(graph.segs.oneway[row])
        if (forward and way >= 0) or (backward and way <= 0):
            return Snap(i, point, c.segment_id, float(c.fraction), float(c.distance_m),
                        forward, backward)
    return None


def no_segment(i: int, point: tuple[float, float], near: Sequence[Candidate],
               opts: PointOptions) -> NoSegmentError:
    """The 422 naming the point and why none of its candidates would do."""
    where = f"point {i} ({point[0]:.6f},{point[1]:.6f})"
    off_globe = [c.segment_id for c in near if c.distance_m is None]
    valid = [c for c in near if c.distance_m is not None]
    if off_globe and not valid:
        return NoSegmentError(f"{where}: the nearest segments ({', '.join(map(str, off_globe))})"
                              " have coordinates outside lon -180..180, lat -90..90; fix the "
                              "network (ugvmap network validate)")
    if not valid:
        return NoSegmentError(f"{where} is farther than {opts.radius_m:g} m from any road: "
                              "no road")
    nearest = valid[0].distance_m
    assert nearest is not None
    if nearest > opts.radius_m:
        return NoSegmentError(f"{where} is farther than {opts.radius_m:g} m from any road: "
                              f"the nearest road is {nearest:.1f} m away")
    return NoSegmentError(f"{where}: no road within {opts.radius_m:g} m can be driven in a "
                          "direction its bearing and approach allow")


def snap_points(conn: Connection, network: str, points: Sequence[tuple[float, float]],
                opts: Sequence[PointOptions], avoid: frozenset[str],
                graph_at: Callable[[int, int], RoadGraph]) -> tuple[RoadGraph, list[Snap]]:
    """Snap every point; ``graph_at(network_id, version)`` gives the graph holding every edit
    the snap statement saw. 404 for an unknown network, 422 naming the first point that
    cannot snap."""
    found = candidates(conn, network, points, avoid)
    graph = graph_at(found.network_id, found.version)
    snaps = []
    for i, point in enumerate(points):
        near = found.near[i]
        snap = choose(graph, near, i, point, opts[i])
        if snap is None and (opts[i].bearing is not None or opts[i].approach != "unrestricted"):
            _, more = _query(conn, FILTERED_SQL, network, [point], avoid, KNN_FILTERED)
            near = more[0]
            snap = choose(graph, near, i, point, opts[i])
        if snap is None:
            raise no_segment(i, point, near, opts[i])
        snaps.append(snap)
    return graph, snaps
