"""Pixel skeleton -> road graph: nodes at junctions and ends, edges along pixel chains.

Junction pixels (more than two skeleton neighbours) that lie within a few metres of each
other are one crossing seen through a wide road, so they are merged into one node; so are two
junctions joined by an edge shorter than their two inscribed road discs together (a wide or
skewed crossing that thinning splits in two). Pixel chains between nodes become edges; nodes
left with exactly two edges are not junctions and are dissolved, so every node a planner sees
is a real junction or a road end. Where each edge runs is :mod:`ingest.roads.geometry`'s job
(sub-pixel, smooth); the pixel chain itself, simplified, is kept as the ``pixel`` geometry for
ablations. Each edge also carries its width (from the road's cross-sections, or twice the
distance from centerline to the mask edge), a lane estimate from it, and a confidence.
Coordinates stay in working-grid pixels here; :class:`~ingest.roads.georef.Frame` maps them
to the output.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Literal

import cv2
import networkx as nx
import numpy as np
from shapely import LineString

from app.road_tuning import DEFAULT_TUNING
from ingest.roads.clean import disk, metres_to_px
from ingest.roads.geometry import confidence, edge_key, refine_geometry
from ingest.roads.georef import Frame
from ingest.roads.ridge import RoadField, soft_mask
from ingest.roads.skeleton import PixelWalker, neighbour_count, trace


@dataclass(frozen=True)
class GraphParams:
    """Graph-building thresholds, in metres."""

    junction_merge_m: float = 4.0
    """Junction pixels closer than this are one node."""
    geometry: Literal["ridge", "pixel"] = "ridge"
    """``ridge``: sub-pixel centres from cross-sections of the soft road field, smoothed
    (:mod:`ingest.roads.geometry`); ``pixel``: the skeleton's pixel chain simplified (the
    geometry before issue 20, kept for ablations)."""
    simplify_m: float = DEFAULT_TUNING.simplify
    """Simplification tolerance for edge geometry (Ramer–Douglas–Peucker; ``ridge`` also
    splits vertices that would turn by more than ``max_turn_deg``)."""
    station_m: float = 1.0
    """Spacing of the cross-sections along a road."""
    smooth_m: float = 15.0
    """Shortest wavelength of a centreline's bends that the smoothing keeps."""
    max_turn_deg: float = 5.0
    """Largest turn at one output vertex, unless the road itself turns that fast."""
    max_half_width_m: float = 15.0
    """How far from the skeleton a cross-section looks for the road's edge."""
    min_segment_m: float = 10.0
    """Isolated pieces (both ends free) shorter than this are dropped as clutter."""
    lane_width_m: float = 3.5


@dataclass(frozen=True)
class Node:
    """A graph node on the working grid."""
    id: int
    xy: tuple[float, float]
    """Working-grid pixel coordinates (pixel corners at integers)."""
    degree: int

    @property
    def is_junction(self) -> bool:
        """Three or more roads meet here."""
        return self.degree >= 3


@dataclass(frozen=True)
class Edge:
    """A road centreline between two nodes, with the width and lanes read from the image."""
    id: int
    source: int
    target: int
    coords: np.ndarray
    """(n, 2) working-grid pixel coordinates from source to target, simplified."""
    length_m: float
    width_m: float
    lanes: int
    confidence: float = 1.0
    """0..1: mean road probability along the centreline (see
    :func:`ingest.roads.geometry.confidence`)."""


@dataclass(frozen=True)
class RoadGraph:
    """The extracted road graph, in working-grid pixels until georeferenced."""
    nodes: list[Node]
    edges: list[Edge]


def _centre(walker: PixelWalker, idx: list[int] | np.ndarray) -> np.ndarray:
    rows, cols = walker.unflat(np.asarray(idx))
    return np.column_stack([cols + 0.5, rows + 0.5]).astype(float)


def _junction_clusters(junction: np.ndarray, merge_px: int) -> tuple[np.ndarray, int]:
    """Cluster id per pixel (-1 elsewhere) for junction pixels within ``merge_px``."""
    grown: np.ndarray = junction.astype(np.uint8)
    if merge_px > 1:
        grown = cv2.dilate(grown, disk(merge_px))
    n, lab = cv2.connectedComponents(grown, connectivity=8)
    cluster = np.where(junction, lab - 1, -1).astype(np.int64)
    used = np.unique(cluster[cluster >= 0])
    remap = np.full(n, -1, np.int64)
    remap[used] = np.arange(len(used))
    return np.where(cluster >= 0, remap[np.maximum(cluster, 0)], -1), len(used)


def _chains(skel: np.ndarray, junction: np.ndarray) -> list[tuple[list[int], bool]]:
    """Ordered flat (padded) pixel indices of every chain between junction pixels, and
    whether it is a closed ring (no ends at all)."""
    chain_mask = skel & ~junction
    walker = PixelWalker(chain_mask)
    n, lab = cv2.connectedComponents(chain_mask.astype(np.uint8), connectivity=8)
    flat = np.flatnonzero(chain_mask.ravel())
    labels = lab.ravel()[flat]
    order = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[order], np.arange(1, n + 1))
    count = neighbour_count(chain_mask).ravel()[flat]
    rows, cols = np.unravel_index(flat, skel.shape)
    padded = walker.flat(rows, cols)
    chains = []
    for k in range(1, n):
        members = order[bounds[k - 1]:bounds[k]]
        ends = members[count[members] <= 1]
        start = int(padded[ends[0] if len(ends) else members[0]])
        path, _ = trace(walker, start)
        chains.append((path, len(ends) == 0))
    return chains


def _skeleton_multigraph(skel: np.ndarray, merge_px: int) -> nx.MultiGraph:
    """Nodes (cluster centroids, free ends) and edges (pixel paths) of a skeleton."""
    skel = skel.astype(bool)
    junction = skel & (neighbour_count(skel) >= 3)
    cluster, n_clusters = _junction_clusters(junction, merge_px)
    full = PixelWalker(skel)
    cluster_flat = np.full(full.on.shape, -1, np.int64)
    jr, jc = np.nonzero(junction)
    cluster_flat[full.flat(jr, jc)] = cluster[jr, jc]
    g = nx.MultiGraph()
    free_ids = itertools.count(n_clusters)
    ids = cluster[jr, jc]
    size = np.bincount(ids, minlength=n_clusters)
    mean_x = np.bincount(ids, weights=jc, minlength=n_clusters) / np.maximum(size, 1) + 0.5
    mean_y = np.bincount(ids, weights=jr, minlength=n_clusters) / np.maximum(size, 1) + 0.5
    for k in range(n_clusters):
        g.add_node(k, xy=(float(mean_x[k]), float(mean_y[k])))

    def attach(pixel: int, avoid: int | None) -> int:
        touching = sorted({int(cluster_flat[n]) for n in full.neighbours(pixel)
                           if cluster_flat[n] >= 0})
        others = [t for t in touching if t != avoid]
        if others or touching:
            return (others or touching)[0]
        node = next(free_ids)
        x, y = _centre(full, [pixel])[0]
        g.add_node(node, xy=(float(x), float(y)))
        return node

    for path, closed in _chains(skel, junction):
        u = attach(path[0], None)
        v = u if closed else attach(path[-1], u if len(path) == 1 else None)
        g.add_edge(u, v, start=u, pixels=path)
    return g


def _oriented(g: nx.MultiGraph, u: int, v: int, key: int, frm: int) -> list[int]:
    """Pixel path of edge (u, v, key) running away from node ``frm``."""
    data = g.edges[u, v, key]
    return data["pixels"] if data["start"] == frm else data["pixels"][::-1]


def _dissolve_degree_two(g: nx.MultiGraph) -> None:
    """Join the two edges of every node that has exactly two (non-loop) edges."""
    for n in list(g.nodes):
        if g.degree(n) != 2 or g.has_edge(n, n):
            continue
        (_, a, ka), (_, b, kb) = list(g.edges(n, keys=True))
        path = _oriented(g, n, a, ka, a) + _oriented(g, n, b, kb, n)
        g.remove_node(n)
        g.add_edge(a, b, start=a, pixels=path)


def _geometry(g: nx.MultiGraph, u: int, v: int, key: int, walker: PixelWalker) -> np.ndarray:
    start = g.edges[u, v, key]["start"]
    end = v if start == u else u
    pts = [np.array([g.nodes[start]["xy"]]), _centre(walker, g.edges[u, v, key]["pixels"]),
           np.array([g.nodes[end]["xy"]])]
    coords = np.vstack(pts)
    keep = np.r_[True, np.any(np.diff(coords, axis=0) != 0, axis=1)]
    return coords[keep]


def _length(coords: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(coords, axis=0), axis=1).sum())


def merge_close_junctions(g: nx.MultiGraph, xy: dict[int, tuple[float, float]],
                          dist: np.ndarray) -> bool:
    """Contract every edge between two junctions whose positions ``xy`` are closer than the
    radii of the road discs inscribed at them (``dist``: distance to the mask edge) added
    up: their crossings overlap, so they are one, which thinning split in two (a skewed or
    very wide crossing). Returns whether anything was merged."""
    h, w = dist.shape

    def radius(n: int) -> float:
        x, y = g.nodes[n]["xy"]
        return float(dist[min(max(int(y), 0), h - 1), min(max(int(x), 0), w - 1)])

    merged = True
    merged_any = False
    while merged:
        merged = False
        for u, v, k in g.edges(keys=True):
            if u == v or g.degree(u) < 3 or g.degree(v) < 3:
                continue
            if math.dist(xy[u], xy[v]) >= radius(u) + radius(v):
                continue
            g.remove_edge(u, v, k)
            (ux, uy), (vx, vy) = g.nodes[u]["xy"], g.nodes[v]["xy"]
            g.nodes[u]["xy"] = ((ux + vx) / 2, (uy + vy) / 2)
            xy[u] = ((xy[u][0] + xy[v][0]) / 2, (xy[u][1] + xy[v][1]) / 2)
            for _, other, data in list(g.edges(v, data=True)):
                start = u if data["start"] == v else data["start"]
                g.add_edge(u, u if other == v else other, start=start, pixels=data["pixels"])
            g.remove_node(v)
            merged = merged_any = True
            break
    return merged_any


def build_graph(skel: np.ndarray, road_mask: np.ndarray, resolution_m: float,
                params: GraphParams = GraphParams(), field: RoadField | None = None
                ) -> RoadGraph:
    """The road graph of a pruned skeleton; ``road_mask`` (cleaned) gives edge widths where
    the cross-sections cannot, and ``field`` (default: the mask, softened) is what the
    ``ridge`` geometry and the confidence are read from."""
    merge_px = max(1, metres_to_px(params.junction_merge_m, resolution_m))
    g = _skeleton_multigraph(skel, merge_px)
    walker = PixelWalker(skel)
    for u, v, k in list(g.edges(keys=True)):
        if u == v and _length(_geometry(g, u, v, k, walker)) <= 2 * merge_px + 2:
            g.remove_edge(u, v, k)
    _dissolve_degree_two(g)
    min_px = params.min_segment_m / resolution_m
    for u, v, k in list(g.edges(keys=True)):
        free = u != v and g.degree(u) == 1 and g.degree(v) == 1
        if free and _length(_geometry(g, u, v, k, walker)) < min_px:
            g.remove_edge(u, v, k)
    g.remove_nodes_from([n for n in list(g.nodes) if g.degree(n) == 0])
    _dissolve_degree_two(g)

    dist = cv2.distanceTransform(road_mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    field = field or RoadField(soft_mask(road_mask), 0.5, None)
    coefficients = field.coefficients()
    spacing = max(params.station_m / resolution_m, 0.5)
    if params.geometry == "ridge":
        # Junctions are compared where the roads' centrelines cross, not where thinning put
        # them: a skewed crossing's two skeleton junctions lie far apart, its roads' do not.
        merged = True
        while merged:
            chains = {edge_key(u, v, k): _centre(walker, g.edges[u, v, k]["pixels"])
                      for u, v, k in g.edges(keys=True)}
            shapes, node_xy = refine_geometry(
                g, chains, field, coefficients, resolution_m, params.station_m,
                params.smooth_m, params.simplify_m, params.max_turn_deg,
                params.max_half_width_m)
            merged = merge_close_junctions(g, dict(node_xy), dist)
    else:
        shapes, node_xy = {}, {n: g.nodes[n]["xy"] for n in g.nodes}
    ids = {n: i for i, n in enumerate(sorted(g.nodes))}
    nodes = [Node(ids[n], node_xy[n], g.degree(n)) for n in sorted(g.nodes)]
    edges: list[Edge] = []
    for u, v, k in g.edges(keys=True):
        shape = shapes.get(edge_key(u, v, k))
        if shape is None:
            pixel = _geometry(g, u, v, k, walker)
            coords = (np.asarray(LineString(pixel).simplify(
                params.simplify_m / resolution_m, preserve_topology=False).coords)
                if len(pixel) >= 2 else pixel)
            width_px = None
            conf = confidence(coefficients, coords, spacing) if len(coords) >= 2 else 0.0
        else:
            coords, width_px, conf = shape.coords, shape.width_px, shape.confidence
        if len(coords) < 2:
            continue
        if width_px is None:
            rows, cols = walker.unflat(np.asarray(g.edges[u, v, k]["pixels"]))
            width_px = max(2.0 * float(np.median(dist[rows, cols])) - 1.0, 1.0)
        width_m = width_px * resolution_m
        start = g.edges[u, v, k]["start"]
        end = v if start == u else u
        edges.append(Edge(len(edges), ids[start], ids[end], coords,
                          round(LineString(coords).length * resolution_m, 2), round(width_m, 2),
                          max(1, round(width_m / params.lane_width_m)), round(conf, 3)))
    return RoadGraph(nodes, edges)


def feature_collection(graph: RoadGraph, frame: Frame, members: dict) -> dict:
    """GeoJSON FeatureCollection of edge LineStrings; nodes ride along in a ``nodes`` member.

    Keeping ``features`` to LineStrings lets any GIS (and the network importer) read it as a
    plain line layer, while source/target ids and the node list keep the topology.
    """
    def out(coords: np.ndarray) -> list[list[float]]:
        xs, ys = frame.to_output @ (coords[:, 0], coords[:, 1])
        return np.column_stack([xs, ys]).round(9 if frame.crs is not None else 3).tolist()

    features = [{
        "type": "Feature", "id": e.id,
        "geometry": {"type": "LineString", "coordinates": out(e.coords)},
        "properties": {"id": e.id, "source": e.source, "target": e.target,
                       "length_m": e.length_m, "width_m": e.width_m, "lanes": e.lanes,
                       "confidence": e.confidence},
    } for e in graph.edges]
    nodes = [{
        "type": "Feature", "id": n.id,
        "geometry": {"type": "Point", "coordinates": out(np.array([n.xy]))[0]},
        "properties": {"id": n.id, "degree": n.degree, "is_junction": n.is_junction},
    } for n in graph.nodes]
    return {"type": "FeatureCollection", **members, "features": features, "nodes": nodes}
