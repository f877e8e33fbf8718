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

Rules 2-4 run in :class:`Noder`, two passes over lines that arrive in chunks (a file can be
read twice instead of held in memory); :func:`build_topology` is the same on one list.

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


def node_kind(degree: int) -> str:
    """``endpoint`` for dead ends, ``junction`` where three or more segment ends meet."""
    if degree >= 3:
        return "junction"
    return "endpoint" if degree == 1 else "node"


@dataclass
class TopoNode:
    """A node being built: where it is and what meets there."""
    coord: Coord
    degree: int = 0
    traffic_light: bool = False
    external_id: str | None = None

    @property
    def kind(self) -> str:
        """junction/endpoint/node, from how many segment ends meet here."""
        return node_kind(self.degree)


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
    """Give lines that cross or touch a shared vertex at each meeting point (lines of fewer
    than two distinct vertices are no lines: they meet nothing)."""
    real = [i for i, line in enumerate(lines) if len({grid_key(c) for c in line.coords}) >= 2]
    geoms = np.array([shapely.LineString(lines[i].coords) for i in real], dtype=object)
    tree = shapely.STRtree(geoms)
    left, right = tree.query(geoms, predicate="intersects")
    extra: dict[int, list[Coord]] = {}
    for i, j in zip(left.tolist(), right.tolist(), strict=True):
        if i < j:
            points = _points_of(geoms[i].intersection(geoms[j]))
            extra.setdefault(real[i], []).extend(points)
            extra.setdefault(real[j], []).extend(points)
    out, added = [], 0
    for i, line in enumerate(lines):
        coords, n = _insert_vertices(line.coords, extra.get(i, ()))
        added += n
        out.append(RoadLine(coords, line.attributes))
    # Each crossing adds a vertex to two lines.
    return out, (added + 1) // 2


@dataclass
class SegmentChunk:
    """Segments split from one chunk of lines, in emission order; node indices are final."""

    source: np.ndarray  # int64 node index
    target: np.ndarray
    offsets: np.ndarray  # int64, len = n + 1, into coords
    coords: np.ndarray  # (n_vertices, 2) canonical lon/lat
    attributes: list[RoadAttributes]

    def __len__(self) -> int:
        return len(self.source)


def _pack(coords: np.ndarray) -> np.ndarray:
    """Grid keys of lon/lat rows as one uint64 each (x cell in the high half, y in the low)."""
    cells = np.rint(coords / GRID_DEG)
    if cells.size and np.abs(cells).max() >= 2**31:
        raise ValueError("coordinates must be lon/lat degrees (EPSG:4326)")
    xy = (cells.astype(np.int64) + 2**31).astype(np.uint64)
    return (xy[:, 0] << np.uint64(32)) | xy[:, 1]


def _flatten(lines: Sequence[RoadLine]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coordinates, keys and line offsets of a chunk, with repeated consecutive vertices
    dropped (a line that keeps fewer than two vertices is empty)."""
    counts = np.fromiter((len(line.coords) for line in lines), np.int64, len(lines))
    coords = np.array([c[:2] for line in lines for c in line.coords],
                      dtype=np.float64).reshape(-1, 2)
    keys = _pack(coords)
    owner = np.repeat(np.arange(len(lines)), counts)
    keep = np.ones(len(keys), bool)
    keep[1:] = (keys[1:] != keys[:-1]) | (owner[1:] != owner[:-1])
    kept = np.bincount(owner[keep], minlength=len(lines))
    kept[kept < 2] = 0  # fewer than two distinct vertices: not a line
    keep &= kept[owner] > 0
    offsets = np.concatenate([[0], np.cumsum(kept)])
    return coords[keep], keys[keep], offsets


class Noder:
    """The noding rules over lines that arrive in chunks, in two passes, in bounded memory.

    Pass 1 (:meth:`scan`) keeps only each vertex's 8-byte grid key and the first coordinates
    seen for it; :meth:`freeze` decides which vertices are nodes. Pass 2 (:meth:`split`) reads
    the same lines again, in the same order, and returns each chunk's segments with their final
    node indices, so a writer can stream them out. Lines and attributes are never all held at
    once: a country-sized OSM extract is read twice from the file instead.
    """

    def __init__(self) -> None:
        self._keys: list[np.ndarray] = []
        self._coords: list[np.ndarray] = []
        self._ends: list[np.ndarray] = []
        self._extras: dict[int, NodePoint] = {}
        self.lines_scanned = 0
        self.duplicates_dropped = 0
        self._seen: set[bytes] = set()
        self._node_pos: list[int] = []
        self._n_nodes = 0

    def add_points(self, points: Iterable[NodePoint]) -> None:
        """Remember node attributes (traffic lights, ids) to attach where a line vertex lands."""
        points = list(points)
        if points:
            keys = _pack(np.array([p.coord[:2] for p in points], dtype=np.float64))
            for key, point in zip(keys.tolist(), points, strict=True):
                self._extras.setdefault(key, point)

    def scan(self, lines: Sequence[RoadLine]) -> None:
        """Pass 1 over one chunk: count how often each vertex is used, to find split points."""
        coords, keys, offsets = _flatten(lines)
        self.lines_scanned += len(lines)
        self._keys.append(keys)
        self._coords.append(coords)
        nonempty = offsets[1:] > offsets[:-1]
        self._ends.append(keys[np.concatenate([offsets[:-1][nonempty],
                                               offsets[1:][nonempty] - 1])])

    def freeze(self) -> None:
        """End of pass 1: the vertex table and which vertices are nodes."""
        keys = np.concatenate(self._keys) if self._keys else np.zeros(0, np.uint64)
        coords = np.concatenate(self._coords) if self._coords else np.zeros((0, 2))
        self._keys = self._coords = []
        self.vertex_keys, first, uses = np.unique(keys, return_index=True, return_counts=True)
        del keys
        self.canonical = coords[first]
        del coords, first
        is_node = uses > 1
        for extra in (np.concatenate(self._ends) if self._ends else np.zeros(0, np.uint64),
                      np.fromiter(self._extras, np.uint64, len(self._extras))):
            pos = np.searchsorted(self.vertex_keys, extra)
            hit = pos < len(self.vertex_keys)
            hit[hit] = self.vertex_keys[pos[hit]] == extra[hit]
            is_node[pos[hit]] = True
        self._ends = []
        self.is_node = is_node
        self.node_index = np.full(len(self.vertex_keys), -1, np.int64)
        self.degree = np.zeros(int(is_node.sum()), np.int32)

    def split(self, lines: Sequence[RoadLine]) -> SegmentChunk:
        """Pass 2: the segments of a chunk (same lines, same order as in pass 1)."""
        _, keys, offsets = _flatten(lines)
        pos = np.searchsorted(self.vertex_keys, keys)
        owner = np.repeat(np.arange(len(lines)), np.diff(offsets))
        at = np.flatnonzero(self.is_node[pos])
        pieces = np.flatnonzero(owner[at[1:]] == owner[at[:-1]]) if len(at) else at
        starts, ends = at[pieces], at[pieces + 1]
        src, dst, seg_offsets, gather, attributes = [], [], [0], [], []
        for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
            run = pos[s:e + 1]
            signature = min(run.tobytes(), run[::-1].tobytes())
            if signature in self._seen:
                self.duplicates_dropped += 1
                continue
            self._seen.add(signature)
            src.append(self._index_of(int(run[0])))
            dst.append(self._index_of(int(run[-1])))
            gather.append(run)
            seg_offsets.append(seg_offsets[-1] + len(run))
            attributes.append(lines[int(owner[s])].attributes)
        source, target = np.array(src, np.int64), np.array(dst, np.int64)
        np.add.at(self.degree, source, 1)
        np.add.at(self.degree, target, 1)
        flat = np.concatenate(gather) if gather else np.zeros(0, np.int64)
        return SegmentChunk(source, target, np.array(seg_offsets, np.int64),
                            self.canonical[flat], attributes)

    def _index_of(self, pos: int) -> int:
        """Nodes are numbered in the order segments first reach them."""
        index = self.node_index[pos]
        if index < 0:
            index = self.node_index[pos] = self._n_nodes
            self._n_nodes += 1
            self._node_pos.append(int(pos))
        return int(index)

    @property
    def node_count(self) -> int:
        """Nodes numbered so far (ids must be reserved for that many)."""
        return self._n_nodes

    def nodes(self) -> tuple[np.ndarray, np.ndarray, list[NodePoint | None]]:
        """After pass 2: coordinates, degree and node attributes (or None) of every node."""
        pos = np.array(self._node_pos, np.int64)
        keys = self.vertex_keys[pos].tolist()
        return self.canonical[pos], self.degree[: self._n_nodes], \
            [self._extras.get(k) for k in keys]


def build_topology(lines: Iterable[RoadLine], *, crossings: bool,
                   node_points: Iterable[NodePoint] = ()) -> Topology:
    """Node and split ``lines`` in memory (both passes over one list); ``node_points`` attach
    node attributes by location."""
    lines = list(lines)
    topo = Topology()
    if crossings and lines:
        lines, topo.crossings_noded = node_crossings(lines)
    noder = Noder()
    noder.add_points(node_points)
    noder.scan(lines)
    noder.freeze()
    chunk = noder.split(lines)
    coords, degree, extras = noder.nodes()
    topo.nodes = [TopoNode((float(x), float(y)), int(d), bool(p and p.traffic_light),
                           p.external_id if p else None)
                  for (x, y), d, p in zip(coords.tolist(), degree.tolist(), extras, strict=True)]
    for i, attributes in enumerate(chunk.attributes):
        piece = chunk.coords[chunk.offsets[i]:chunk.offsets[i + 1]]
        topo.segments.append(TopoSegment([(float(x), float(y)) for x, y in piece.tolist()],
                                         int(chunk.source[i]), int(chunk.target[i]), attributes))
    topo.duplicates_dropped = noder.duplicates_dropped
    return topo
