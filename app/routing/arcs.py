"""The arcs of a graph shape: every non-loop segment in both directions, in CSR order.

One table serves both searches. Sorted by tail then head, it *is* the sparse structure of
the Dijkstra matrix (``indptr`` / ``head``), and its positions are the contraction
hierarchy's input arc ids. A cost model then only needs one weight per arc (infinite where
a direction is not allowed), so an edit changes weights at the arcs of the edited rows
(:meth:`Arcs.of_rows`) and never re-sorts anything. It depends only on which segments join
which nodes, so every graph version with the same segment ends shares it.

Parallel segments stay separate arcs: scipy's Dijkstra relaxes each and keeps the cheaper,
and :meth:`Arcs.cheapest` picks the same one when a node path is turned back into segments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Arcs:
    """Arc table of one shape, sorted by (tail, head)."""

    tail: np.ndarray  # uint32 node index, ascending
    head: np.ndarray  # uint32 node index, ascending within a tail
    row: np.ndarray  # int64 segment row
    way: np.ndarray  # int8: +1 along the geometry, -1 against it
    indptr: np.ndarray  # int32, n_nodes + 1: the arcs leaving node i are indptr[i]:indptr[i+1]
    by_row: np.ndarray  # int64 (n_rows, 2): each row's forward and backward arc, -1 for loops
    key: np.ndarray  # int64 tail * n_nodes + head, ascending: finds the arcs joining two nodes

    @classmethod
    def of(cls, u: np.ndarray, v: np.ndarray, n_nodes: int) -> Arcs:
        """Both directions of every segment from node ``u`` to ``v``; loops carry no route."""
        rows = np.flatnonzero(u != v)
        tail = np.concatenate([u[rows], v[rows]]).astype(np.uint32)
        head = np.concatenate([v[rows], u[rows]]).astype(np.uint32)
        order = np.lexsort((head, tail))
        by_row = np.full((len(u), 2), -1, np.int64)
        position = np.empty(len(order), np.int64)
        position[order] = np.arange(len(order))
        by_row[rows, 0], by_row[rows, 1] = position[: len(rows)], position[len(rows):]
        way = np.concatenate([np.ones(len(rows), np.int8), -np.ones(len(rows), np.int8)])
        tail, head = tail[order], head[order]
        return cls(tail, head, np.concatenate([rows, rows])[order], way[order],
                   np.searchsorted(tail, np.arange(n_nodes + 1)).astype(np.int32), by_row,
                   tail.astype(np.int64) * n_nodes + head)

    def spliced(self, row_map: np.ndarray, node_map: np.ndarray, n_nodes: int, n_rows: int,
                rows: np.ndarray, u: np.ndarray, v: np.ndarray) -> Arcs:
        """This table after an edit: arcs of dropped rows (``row_map`` -1) removed, rows and
        nodes renumbered (both maps keep their order, so the kept arcs stay sorted), and the
        arcs of new ``rows`` (from node ``u`` to ``v``) inserted where they sort."""
        keep = row_map[self.row] >= 0
        tail, head = node_map[self.tail[keep]], node_map[self.head[keep]]
        key = tail * n_nodes + head
        new = Arcs.of(u, v, n_nodes)
        at = np.searchsorted(key, new.key, side="right")
        tail = np.insert(tail, at, new.tail).astype(np.uint32)
        row = np.insert(row_map[self.row[keep]], at, rows[new.row])
        way = np.insert(self.way[keep], at, new.way)
        by_row = np.full((n_rows, 2), -1, np.int64)
        by_row[row, (way < 0).astype(np.intp)] = np.arange(len(row))
        return Arcs(tail, np.insert(head, at, new.head).astype(np.uint32), row, way,
                    np.searchsorted(tail, np.arange(n_nodes + 1)).astype(np.int32), by_row,
                    np.insert(key, at, new.key))

    def __len__(self) -> int:
        return len(self.tail)

    @property
    def n_nodes(self) -> int:
        """Number of nodes (rows of the CSR structure)."""
        return len(self.indptr) - 1

    def of_rows(self, rows: np.ndarray) -> np.ndarray:
        """The arcs of segment ``rows`` (both directions, loops have none)."""
        arcs = self.by_row[rows].ravel()
        return arcs[arcs >= 0]

    def cheapest(self, tails: np.ndarray, heads: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """For each pair ``tails[k] -> heads[k]`` of joined nodes, the cheapest arc from one to
        the other (consecutive nodes of a path, or each node and its search predecessor)."""
        steps = tails.astype(np.int64) * self.n_nodes + heads
        lo = np.searchsorted(self.key, steps, side="left")
        hi = np.searchsorted(self.key, steps, side="right")
        for k in np.flatnonzero(hi - lo > 1).tolist():  # parallel segments: rare
            lo[k] += int(np.argmin(weights[lo[k]:hi[k]]))
        return lo
