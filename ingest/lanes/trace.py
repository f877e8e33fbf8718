"""Painted blobs -> measured pieces of line.

The paint is thinned, its short spurs pruned, and the skeleton cut at its junctions: a stop
line touching the lane lines at its ends, or an arrow touching a line, becomes pieces of its
own instead of one bent blob. Each branch's longest geodesic path (two Dijkstra passes over
its 8-connected pixels) is the piece's line: a dash, a stretch of solid line, a stop line or
an arrow's shaft. Its width is twice the distance from that line to the paint's edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from ingest.roads.skeleton import neighbour_count, prune_spurs, thin

_OFFSETS = ((0, 1, 1.0), (1, 0, 1.0), (1, 1, 2**0.5), (1, -1, 2**0.5))


@dataclass(frozen=True)
class Piece:
    """One blob of paint as a line, in pixel coordinates (x = column, y = row, corners at
    integers)."""

    coords: np.ndarray
    """(N, 2) the line through the blob, simplified."""
    length_px: float
    width_px: float
    rows: np.ndarray
    cols: np.ndarray
    """The piece's skeleton pixels, the paint's core (colour and contrast are read there)."""

    heads: np.ndarray
    """(2, 2) unit directions of travel at the start and at the end, over the last ~2 m."""

    def flipped(self) -> Piece:
        """The same piece travelled the other way."""
        return Piece(self.coords[::-1].copy(), self.length_px, self.width_px, self.rows,
                     self.cols, -self.heads[::-1])


def _heads(coords: np.ndarray, reach_px: float) -> np.ndarray:
    """Directions of travel at both ends of a line, each averaged over ``reach_px`` (a dash is
    short: often its whole length)."""
    line = shapely.LineString(coords)
    a = line.interpolate(max(line.length - reach_px, 0.0))
    b = line.interpolate(min(reach_px, line.length))
    d = np.array([[b.x - coords[0][0], b.y - coords[0][1]],
                  [coords[-1][0] - a.x, coords[-1][1] - a.y]])
    return d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)[:, None]


def _longest_path(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Indices into rows/cols of the longest shortest path through the skeleton pixels."""
    n = len(rows)
    r0, c0 = rows.min(), cols.min()
    grid = np.full((rows.max() - r0 + 3, cols.max() - c0 + 3), -1, np.int64)
    grid[rows - r0 + 1, cols - c0 + 1] = np.arange(n)
    src, dst, weight = [], [], []
    for dr, dc, w in _OFFSETS:
        other = grid[rows - r0 + 1 + dr, cols - c0 + 1 + dc]
        hit = other >= 0
        src.append(np.flatnonzero(hit))
        dst.append(other[hit])
        weight.append(np.full(int(hit.sum()), w))
    graph = coo_matrix((np.concatenate(weight), (np.concatenate(src), np.concatenate(dst))),
                       shape=(n, n)).tocsr()
    far = dijkstra(graph, directed=False, indices=0)
    a = int(np.argmax(np.where(np.isfinite(far), far, -1)))
    dist, pred = dijkstra(graph, directed=False, indices=a, return_predecessors=True)
    b = int(np.argmax(np.where(np.isfinite(dist), dist, -1)))
    path = [b]
    while path[-1] != a:
        path.append(int(pred[path[-1]]))
    return np.array(path[::-1])


def pieces(mask: np.ndarray, resolution_m: float, min_length_m: float = 0.5,
           simplify_px: float = 0.6, head_m: float = 2.0, spur_m: float = 0.3) -> list[Piece]:
    """One :class:`Piece` per skeleton branch of ``mask`` whose bounding box's diagonal
    reaches ``min_length_m`` (smaller specks are no marking)."""
    min_px = min_length_m / resolution_m
    skel = prune_spurs(thin(mask), spur_m / resolution_m)
    junction = (skel & (neighbour_count(skel) >= 3)).astype(np.uint8)
    branches = skel & ~cv2.dilate(junction, np.ones((3, 3), np.uint8)).astype(bool)
    dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(branches.astype(np.uint8),
                                                                 connectivity=8)
    out = []
    for label in range(1, count):
        x, y, w, h, _ = stats[label]
        if w * w + h * h < min_px * min_px:
            continue
        sr, sc = np.nonzero(labels[y:y + h, x:x + w] == label)
        path = _longest_path(sr, sc)
        if len(path) < 2:
            continue
        xy = np.column_stack([sc[path] + x + 0.5, sr[path] + y + 0.5]).astype(float)
        length = float(np.hypot(*np.diff(xy, axis=0).T).sum()) + 1.0
        coords = np.asarray(shapely.LineString(xy).simplify(simplify_px).coords)
        rows, cols = sr + y, sc + x
        width = max(2.0 * float(np.median(dist[rows, cols])) - 1.0, 1.0)
        out.append(Piece(coords, length, width, rows, cols,
                         _heads(coords, head_m / resolution_m)))
    return out
