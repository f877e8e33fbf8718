"""Turn attributed polylines into a node/segment topology (pure: no database).

Rules, in order:

1. Optionally (files without a topology of their own) lines that cross or touch get a vertex
   at every intersection, in both lines, with the same coordinates.
2. Vertices are identified on a 1e-7 degree grid (about 1 cm, OpenStreetMap's own precision)
   and snapped to the first coordinate seen for their cell, so lines that meet share the very
   same point.
3. A vertex is a node when it ends a line, is used more than once (by several lines, or twice
   by one) or carries node attributes (a traffic light). Lines are split at every node.
4. Segments with the same vertex sequence (either direction) are duplicates: the first wins.

The rules are idempotent: noding the output of a noding again changes nothing, which is what
makes export/import round-trips lossless.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from ingest.network.model import Coord, NodePoint, RoadAttributes, RoadLine

GRID_DEG = 1e-7

Key = tuple[int, int]


@dataclass
class TopoNode:
    """A node being built: where it is and what meets there."""
    coord: Coord
    degree: int = 0
    traffic_light: bool = False
    external_id: str | None = None

    @property
    def kind(self) -> str:
        """``endpoint`` for dead ends, ``junction`` where three or more segment ends meet."""
        if self.degree >= 3:
            return "junction"
        return "endpoint" if self.degree == 1 else "node"


@dataclass
class TopoSegment:
    """A segment between two node indexes."""
    coords: list[Coord]
    source: int
    target: int
    attributes: RoadAttributes


@dataclass
class Topology:
    """The noded network, and what noding did (for the import summary)."""
    nodes: list[TopoNode] = field(default_factory=list)
    segments: list[TopoSegment] = field(default_factory=list)
    duplicates_dropped: int = 0
    crossings_noded: int = 0


def grid_key(coord: Coord) -> Key:
    """Coordinates snapped to a 1e-7 degree (~1 cm) grid, so vertices that differ only by float
    noise meet."""
    return round(coord[0] / GRID_DEG), round(coord[1] / GRID_DEG)


def _points_of(geom: BaseGeometry) -> list[Coord]:
    """Intersection points of two lines; an overlap contributes its two ends."""
    if geom.is_empty:
        return []
    if geom.geom_type == "Point":
        return [(geom.x, geom.y)]
    if geom.geom_type == "LineString":
        return [geom.coords[0], geom.coords[-1]]
    return [p for part in geom.geoms for p in _points_of(part)]


def _insert_vertices(coords: list[Coord], points: Iterable[Coord]) -> tuple[list[Coord], int]:
    """Insert each point into the polyline at its position along it; returns (coords, added)."""
    existing = {grid_key(c) for c in coords}
    fresh = {grid_key(p): p for p in points if grid_key(p) not in existing}
    if not fresh:
        return coords, 0
    line = shapely.LineString(coords)
    xy = np.asarray(coords)
    cumulative = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    placed = []
    for p in fresh.values():
        d = line.project(shapely.Point(p))
        index = min(int(np.searchsorted(cumulative, d, side="right")) - 1, len(coords) - 2)
        placed.append((index, d, p))
    placed.sort()
    out: list[Coord] = []
    cursor = 0
    for index, _, p in placed:
        out.extend(coords[cursor:index + 1])
        cursor = index + 1
        out.append(p)
    out.extend(coords[cursor:])
    return out, len(placed)


def node_crossings(lines: Sequence[RoadLine]) -> tuple[list[RoadLine], int]:
    """Give lines that cross or touch a shared vertex at each meeting point."""
    geoms = np.array([shapely.LineString(line.coords) for line in lines], dtype=object)
    tree = shapely.STRtree(geoms)
    left, right = tree.query(geoms, predicate="intersects")
    extra: dict[int, list[Coord]] = {}
    for i, j in zip(left.tolist(), right.tolist(), strict=True):
        if i < j:
            points = _points_of(geoms[i].intersection(geoms[j]))
            extra.setdefault(i, []).extend(points)
            extra.setdefault(j, []).extend(points)
    out, added = [], 0
    for i, line in enumerate(lines):
        coords, n = _insert_vertices(line.coords, extra.get(i, ()))
        added += n
        out.append(RoadLine(coords, line.attributes))
    # Each crossing adds a vertex to two lines.
    return out, (added + 1) // 2


def build_topology(lines: Iterable[RoadLine], *, crossings: bool,
                   node_points: Iterable[NodePoint] = ()) -> Topology:
    """Node and split ``lines``; ``node_points`` attach node attributes by location."""
    cleaned = [line for line in lines if len({grid_key(c) for c in line.coords}) >= 2]
    topo = Topology()
    if crossings and cleaned:
        cleaned, topo.crossings_noded = node_crossings(cleaned)

    canonical: dict[Key, Coord] = {}
    keyed: list[tuple[list[Key], RoadAttributes]] = []
    uses: dict[Key, int] = {}
    ends: set[Key] = set()
    for line in cleaned:
        keys: list[Key] = []
        for c in line.coords:
            k = grid_key(c)
            canonical.setdefault(k, (float(c[0]), float(c[1])))
            if not keys or keys[-1] != k:
                keys.append(k)
        for k in keys:
            uses[k] = uses.get(k, 0) + 1
        ends.update((keys[0], keys[-1]))
        keyed.append((keys, line.attributes))

    extras = {grid_key(p.coord): p for p in node_points}
    is_node = ends | {k for k, n in uses.items() if n > 1} | (extras.keys() & uses.keys())
    node_index: dict[Key, int] = {}

    def node_of(k: Key) -> int:
        if k not in node_index:
            node_index[k] = len(topo.nodes)
            extra = extras.get(k)
            topo.nodes.append(TopoNode(
                canonical[k], traffic_light=bool(extra and extra.traffic_light),
                external_id=extra.external_id if extra else None))
        return node_index[k]

    seen: set[tuple[Key, ...]] = set()
    for keys, attributes in keyed:
        start = 0
        for i in range(1, len(keys)):
            if keys[i] not in is_node:
                continue
            piece = tuple(keys[start:i + 1])
            start = i
            signature = min(piece, piece[::-1])
            if signature in seen:
                topo.duplicates_dropped += 1
                continue
            seen.add(signature)
            source, target = node_of(piece[0]), node_of(piece[-1])
            topo.nodes[source].degree += 1
            topo.nodes[target].degree += 1
            topo.segments.append(TopoSegment([canonical[k] for k in piece], source, target,
                                             attributes))
    return topo
