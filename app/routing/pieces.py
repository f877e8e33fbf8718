"""Why no route joins two points, said so a person can act on it: which connected piece of the
network each point is on, and how big each piece is.

An extracted network often falls apart into pieces (a gap the model did not bridge), and
"no route from point 1 to point 2" alone leaves the user guessing between a typo, a one-way
street and a missing road. A *piece* is what the roads this request may drive join, in
either direction (the weakly connected components of the allowed arcs: one-way rules and
avoided classes applied). Points on different pieces cannot be joined by any route, so the
message names both pieces with their sizes; points on one piece with no route between them
are kept apart by direction (one-way roads, or the bearings and approaches asked for).

Computed only when a route fails, once per request: a few passes over the arcs, 70-80 ms on
a million segments (``bench/route_pieces.py``), less than the failed search before it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from app.errors import NoRouteError
from app.routing.graph import CostGraph, RoadGraph
from app.routing.params import point


@dataclass(frozen=True)
class Pieces:
    """The pieces of one graph under one cost model: each segment row's piece, and each
    piece's count and length of drivable segments."""

    of_row: np.ndarray
    segments: np.ndarray
    length_m: np.ndarray
    avoid: frozenset[str]  # the left-out classes (avoided, or not for this vehicle) it holds

    @classmethod
    def of(cls, graph: RoadGraph, cg: CostGraph) -> Pieces:
        """Label the nodes joined by allowed arcs; count each piece's drivable segments. The
        arc table is already sorted by tail, so the allowed arcs are its CSR structure as is
        (no COO sort), and a mask replaces ``np.unique``."""
        arcs, n = cg.arcs, cg.arcs.n_nodes
        allowed = np.isfinite(cg.arc_costs)
        indptr = np.concatenate([[0], np.cumsum(np.bincount(arcs.tail[allowed], minlength=n))])
        joins = csr_matrix((np.ones(int(allowed.sum()), np.int8),
                            arcs.head[allowed].astype(np.int32), indptr.astype(np.int32)),
                           shape=(n, n))
        count, of_node = connected_components(joins, directed=True, connection="weak")
        drivable = np.zeros(len(graph.segs), bool)
        drivable[arcs.row[allowed]] = True
        of_row = of_node[graph.u]
        # Only the left-out classes this network has: the vehicle profile's list (footway,
        # steps, ...) means nothing to the reader of a network that holds none of them.
        classes = graph.segs.road_class.astype(str)
        held = np.unique(classes[np.isin(classes, list(cg.avoid))]) if cg.avoid else ()
        return cls(of_row, np.bincount(of_row[drivable], minlength=count),
                   np.bincount(of_row[drivable], weights=graph.segs.length_m[drivable],
                               minlength=count), frozenset(str(c) for c in held))

    def size(self, piece: int) -> str:
        """A piece's size in words: "12 segments (0.8 km)"."""
        count, metres = int(self.segments[piece]), float(self.length_m[piece])
        if metres < 1000:
            length = f"{metres:.0f} m"
        elif metres < 10_000:
            length = f"{metres / 1000:.1f} km"
        else:
            length = f"{metres / 1000:,.0f} km"
        return f"{count:,} segment{'' if count == 1 else 's'} ({length})"

    def no_route(self, i: int, row_i: int, j: int, row_j: int) -> NoRouteError:
        """The 422 for points ``i`` and ``j`` (0-based; snapped onto segment rows ``row_i``
        and ``row_j``) that no route joins: on different pieces (named, with their sizes), or
        on one piece and kept apart by direction."""
        a, b = int(self.of_row[row_i]), int(self.of_row[row_j])
        head = f"no route from {point(i)} to {point(j)}: "
        left_out = (f" once roads of the classes not driven ({', '.join(sorted(self.avoid))}) "
                    "are left out" if self.avoid else "")
        if a != b:
            return NoRouteError(
                f"{head}{point(i)} is on a piece of the network of {self.size(a)} and "
                f"{point(j)} on another of {self.size(b)}{left_out}: no road joins them")
        return NoRouteError(
            f"{head}both are on one piece of the network ({self.size(a)}){left_out}, but its "
            f"one-way roads (or the bearings and approaches asked for) lead no way from "
            f"{point(i)} to {point(j)}")
