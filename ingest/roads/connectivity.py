"""Connectivity of an extracted road graph: APLS (Average Path Length Similarity).

Buffer precision/recall says whether the pixels are right; a planner needs the *routes* to be
right, and a 3 m gap that costs nothing in recall can turn a 200 m trip into a 2 km detour.
APLS (SpaceNet 3, Van Etten 2018) compares shortest-path lengths between matched node pairs:
each pair scores ``1 - min(1, |L_a - L_b| / L_a)`` (0 when an end has no match or the path
does not exist in the other graph), averaged; it is computed both ways (truth -> prediction
penalises gaps, prediction -> truth penalises spurious shortcuts) and combined by harmonic
mean.

How nodes are matched (simplified from SpaceNet's reference code, which also inserts extra
control points every 50 m along long edges; we do not, so only ends, junctions and shared
vertices are sampled): a node of graph A matches

1. the nearest node of graph B within ``snap_radius``, if there is one; junctions and ends
   are what a shift of the whole road moves together, and matching node to node keeps a
   shifted crossing exact instead of landing on either of its two roads;
2. otherwise the nearest point on an edge of B within ``snap_radius``, where a node is
   inserted (the edge is split there), so a truth node in the middle of a predicted road is
   matched instead of scoring 0;
3. otherwise nothing, and every pair with that node scores 0.

Coordinates are whatever the caller uses (metres or pixels); ``snap_radius`` is in the same
unit. Shortest paths run on scipy's compiled Dijkstra.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Sequence

import networkx as nx
import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

PRESERVED = 0.1
"""A pair's path length is "preserved" within this relative error."""
_CHUNK = 64
"""Dijkstra sources per call: bounds the (sources x nodes) distance matrix."""


def _length(coords: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(coords, axis=0), axis=1).sum())


def _add_edge(g: nx.Graph, u: int, v: int, coords: np.ndarray, ids: Iterator[int]) -> None:
    """Add edge u-v with its geometry; a loop or a second u-v edge is split at its middle.

    ``nx.Graph`` keeps one edge per node pair, and two roads between the same two junctions
    (or a ring) are both real: splitting keeps each as its own path and geometry.
    """
    length = _length(coords)
    if length == 0:
        return
    if u != v and not g.has_edge(u, v):
        g.add_edge(u, v, weight=length, coords=coords, start=u)
        return
    cum = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(coords, axis=0), axis=1))]
    first, second = _split(coords, cum, [length / 2])
    m = next(ids)
    g.add_node(m, xy=tuple(first[-1]), control=False)
    _add_edge(g, u, m, first, ids)
    _add_edge(g, m, v, second, ids)


def _split(coords: np.ndarray, cum: np.ndarray, at: Sequence[float]) -> list[np.ndarray]:
    """Polyline ``coords`` (cumulative lengths ``cum``) cut at increasing arc lengths ``at``
    (all strictly inside) into ``len(at) + 1`` pieces."""
    bounds = [0.0, *at, float(cum[-1])]
    pieces = []
    for s0, s1 in itertools.pairwise(bounds):
        inner = coords[(cum > s0) & (cum < s1)]
        ends = np.array([np.interp(s, cum, coords[:, k]) for s in (s0, s1) for k in (0, 1)])
        pieces.append(np.vstack([ends[:2], inner, ends[2:]]))
    return pieces


def graph_from_lines(lines: Sequence[np.ndarray], snap: float = 1e-6) -> nx.Graph:
    """Road graph of polylines: nodes at line ends and at vertices shared by lines.

    Vertices closer than ``snap`` are one point. Lines that cross without a shared vertex stay
    unconnected (a bridge over a road). Nodes carry ``xy`` and ``control`` (True for ends and
    shared vertices; False for the helper nodes that split loops and parallel edges); edges
    carry ``weight`` (Euclidean length along the polyline), ``coords`` ((n, 2), running from
    node ``start``) and ``start``.
    """
    g = nx.Graph()
    arrays = [a for a in (np.atleast_2d(np.asarray(line, float))[:, :2] for line in lines)
              if a.shape == (len(a), 2) and len(a) >= 2]
    if not arrays:
        return g
    pts = np.concatenate(arrays)
    n = len(pts)
    pairs = cKDTree(pts).query_pairs(snap, output_type="ndarray") if snap > 0 else None
    if pairs is not None and len(pairs):
        adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        _, cluster = connected_components(adj, directed=False)
    else:
        _, cluster = np.unique(pts, axis=0, return_inverse=True)
        cluster = cluster.ravel()
    n_clusters = int(cluster.max()) + 1
    size = np.bincount(cluster, minlength=n_clusters)
    rep = np.column_stack([np.bincount(cluster, weights=pts[:, k], minlength=n_clusters)
                           for k in (0, 1)]) / size[:, None]

    sequences = []
    start = 0
    for a in arrays:
        seq = cluster[start:start + len(a)]
        start += len(a)
        seq = seq[np.r_[True, seq[1:] != seq[:-1]]]
        if len(seq) >= 2:
            sequences.append(seq)
    if not sequences:
        return g
    uses = np.bincount(np.concatenate(sequences), minlength=n_clusters)
    is_node = uses >= 2
    for seq in sequences:
        is_node[seq[[0, -1]]] = True
    for k in np.flatnonzero(is_node):
        g.add_node(int(k), xy=(float(rep[k, 0]), float(rep[k, 1])), control=True)
    ids = itertools.count(n_clusters)
    for seq in sequences:
        cuts = np.flatnonzero(is_node[seq])
        for i, j in itertools.pairwise(cuts):
            _add_edge(g, int(seq[i]), int(seq[j]), rep[seq[i:j + 1]], ids)
    return g


def _control_nodes(g: nx.Graph) -> list[int]:
    return [n for n, d in g.nodes(data=True) if d["control"]]


def _sample_pairs(g: nx.Graph, n_pairs: int, rng: np.random.Generator) -> list[tuple[int, int]]:
    """Up to ``n_pairs`` distinct pairs of control nodes that a path joins in ``g``: all of
    them when there are few, else uniformly drawn over all connected pairs."""
    groups = []
    for comp in nx.connected_components(g):
        members = sorted(n for n in comp if g.nodes[n]["control"])
        if len(members) >= 2:
            groups.append(members)
    weights = np.array([len(m) * (len(m) - 1) // 2 for m in groups], float)
    if weights.sum() <= n_pairs:
        return [p for m in groups for p in itertools.combinations(m, 2)]
    chosen: set[tuple[int, int]] = set()
    while len(chosen) < n_pairs:
        members = groups[rng.choice(len(groups), p=weights / weights.sum())]
        i, j = rng.choice(len(members), 2, replace=False)
        a, b = members[i], members[j]
        chosen.add((min(a, b), max(a, b)))
    return sorted(chosen)


def _path_lengths(g: nx.Graph, pairs: Sequence[tuple[int, int]]) -> np.ndarray:
    """Shortest-path length of each (source, target) pair in ``g`` (inf when disconnected)."""
    order = list(g.nodes)
    index = {n: i for i, n in enumerate(order)}
    matrix = nx.to_scipy_sparse_array(g, nodelist=order, weight="weight", format="csr")
    src = np.array([index[s] for s, _ in pairs], np.intp)
    dst = np.array([index[t] for _, t in pairs], np.intp)
    out = np.full(len(pairs), np.inf)
    sources, which = np.unique(src, return_inverse=True)
    for lo in range(0, len(sources), _CHUNK):
        dist = dijkstra(matrix, directed=False, indices=sources[lo:lo + _CHUNK])
        sel = (which >= lo) & (which < lo + _CHUNK)
        out[sel] = dist[which[sel] - lo, dst[sel]]
    return out


def _snap(g: nx.Graph, points: np.ndarray, radius: float) -> tuple[nx.Graph, list[int | None]]:
    """Copy of ``g`` with nodes inserted where ``points`` snap onto edges, and each point's
    node (None: nothing within ``radius``). See the module doc for the rule."""
    g = g.copy()
    match: list[int | None] = [None] * len(points)
    control = _control_nodes(g)
    if not control or not len(points):
        return g, match
    xy = np.array([g.nodes[n]["xy"] for n in control])
    dist, nearest = cKDTree(xy).query(points, distance_upper_bound=radius)
    for i in np.flatnonzero(np.isfinite(dist)).tolist():
        match[i] = control[nearest[i]]
    rest = np.flatnonzero(~np.isfinite(dist))
    edges = list(g.edges(data=True))
    if not len(rest) or not edges:
        return g, match
    geoms = np.array([shapely.LineString(d["coords"]) for _, _, d in edges], dtype=object)
    probes = shapely.points(points[rest])
    hit, on = shapely.STRtree(geoms).query_nearest(probes, max_distance=radius,
                                                   all_matches=False)
    at = shapely.line_locate_point(geoms[on], probes[hit])
    inserts: dict[int, list[tuple[float, int]]] = {}
    for h, e, s in zip(hit, on, at, strict=True):
        inserts.setdefault(int(e), []).append((float(s), int(rest[h])))
    ids = itertools.count(max(g.nodes) + 1)
    eps = 1e-9 * max(1.0, float(np.abs(xy).max()))
    for e, items in inserts.items():
        u, v, data = edges[e]
        first = data["start"]
        last = v if first == u else u
        coords = data["coords"]
        length = data["weight"]
        cuts: list[float] = []
        new: list[int] = []
        for s, i in sorted(items):
            if s <= eps:
                match[i] = first
            elif s >= length - eps:
                match[i] = last
            else:
                if not cuts or s - cuts[-1] > eps:
                    cuts.append(s)
                    new.append(next(ids))
                match[i] = new[-1]
        if not cuts:
            continue
        cum = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(coords, axis=0), axis=1))]
        pieces = _split(coords, cum, cuts)
        for n, piece in zip(new, pieces, strict=False):
            g.add_node(n, xy=(float(piece[-1, 0]), float(piece[-1, 1])), control=False)
        g.remove_edge(u, v)
        chain = [first, *new, last]
        for a, b, piece in zip(chain[:-1], chain[1:], pieces, strict=True):
            g.add_edge(a, b, weight=_length(piece), coords=piece, start=a)
    return g, match


def _one_way(a: nx.Graph, b: nx.Graph, snap_radius: float, n_pairs: int,
             rng: np.random.Generator) -> np.ndarray:
    """Relative path-length error of sampled connected pairs of ``a`` in ``b`` (inf: an end
    unmatched or no path in ``b``); empty when ``a`` has no connected pair."""
    pairs = _sample_pairs(a, n_pairs, rng)
    if not pairs:
        return np.zeros(0)
    len_a = _path_lengths(a, pairs)
    used = sorted({n for p in pairs for n in p})
    points = np.array([a.nodes[n]["xy"] for n in used], float)
    snapped, match = _snap(b, points, snap_radius)
    to_b = dict(zip(used, match, strict=True))
    matched = [(i, to_b[s], to_b[t]) for i, (s, t) in enumerate(pairs)]
    found = [(i, s, t) for i, s, t in matched if s is not None and t is not None]
    len_b = np.full(len(pairs), np.inf)
    if found:
        len_b[[i for i, _, _ in found]] = _path_lengths(snapped, [(s, t) for _, s, t in found])
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(len_b), np.abs(len_a - len_b) / len_a, np.inf)


def _score(errors: np.ndarray) -> float:
    return float((1 - np.minimum(1, errors)).mean()) if len(errors) else 0.0


def connectivity_report(gt_lines: Sequence[np.ndarray], pred_lines: Sequence[np.ndarray],
                        snap_radius: float, *, n_pairs: int = 500, seed: int = 0) -> dict:
    """APLS both ways, their harmonic mean (``apls``), and ``pairs_preserved``: the share of
    sampled truth pairs whose path length the prediction keeps within 10 %. Every score is 0
    when either side has no connected pair of nodes."""
    gt, pred = graph_from_lines(gt_lines), graph_from_lines(pred_lines)
    rng = np.random.default_rng(seed)
    errors = _one_way(gt, pred, snap_radius, n_pairs, rng)
    gt_to_pred = _score(errors)
    pred_to_gt = _score(_one_way(pred, gt, snap_radius, n_pairs, rng))
    total = gt_to_pred + pred_to_gt
    return {"apls": 2 * gt_to_pred * pred_to_gt / total if total > 0 else 0.0,
            "gt_to_pred": gt_to_pred, "pred_to_gt": pred_to_gt,
            "pairs_preserved": float((errors <= PRESERVED).mean()) if len(errors) else 0.0}


def apls(gt_lines: Sequence[np.ndarray], pred_lines: Sequence[np.ndarray], *,
         n_pairs: int = 500, snap_radius: float, seed: int = 0) -> float:
    """Symmetric APLS in [0, 1] of predicted against truth polylines (see module doc);
    0.0 for an empty prediction or truth."""
    return connectivity_report(gt_lines, pred_lines, snap_radius, n_pairs=n_pairs,
                               seed=seed)["apls"]
