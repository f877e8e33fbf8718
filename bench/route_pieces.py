"""What a failed route costs to explain: the connected pieces of a million-segment graph.

    .venv/bin/python bench/route_pieces.py [--side 710]

Builds a two-way street grid of nearly ``2 * side * (side - 1)`` segments in memory (no
database; 710 gives 1,006,070), cut in two by leaving out the streets that would cross its
middle, with its time cost graph; then times :meth:`app.routing.pieces.Pieces.of` (labelling
the pieces and sizing them: what a ``NoRoute`` answer adds to the failed search) three times
and prints the message for points at opposite corners.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
# The contraction hierarchy is not what is measured: never build one for this graph.
os.environ["UGVMAP_ROUTING_HIERARCHY_MIN_SEGMENTS"] = str(10**9)

from app.routing.costs import Cost
from app.routing.graph import RoadGraph, Segments
from app.routing.pieces import Pieces


def grid(side: int) -> Segments:
    """A side x side grid of nodes 0.001 deg apart, every block a 100 m two-way segment,
    without the north-south blocks across the middle (two pieces)."""
    node = np.arange(side * side).reshape(side, side)
    middle = side // 2
    ends = np.concatenate([np.stack([node[:, :-1].ravel(), node[:, 1:].ravel()], 1),
                           np.stack([node[:middle - 1, :].ravel(), node[1:middle, :].ravel()], 1),
                           np.stack([node[middle:-1, :].ravel(), node[middle + 1:, :].ravel()],
                                    1)])
    n = len(ends)
    coords = np.stack([(ends % side).ravel() * 1e-3, (ends // side).ravel() * 1e-3], 1)
    return Segments(
        ids=np.arange(n, dtype=np.int64), source=ends[:, 0].astype(np.int64),
        target=ends[:, 1].astype(np.int64), length_m=np.full(n, 100.0),
        speed_limit=np.full(n, 50.0), oneway=np.zeros(n, np.int8),
        lanes_forward=np.ones(n, np.int16), lanes_backward=np.ones(n, np.int16),
        road_class=np.full(n, "residential", dtype=object), name=np.full(n, None, dtype=object),
        ref=np.full(n, None, dtype=object), roundabout=np.zeros(n, bool),
        offsets=np.arange(0, 2 * n + 1, 2, dtype=np.int64), coords=coords)


def main() -> None:
    """Build the grid, time the pieces, show the message."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--side", type=int, default=710)
    args = parser.parse_args()
    segs = grid(args.side)
    graph = RoadGraph(1, 1, segs)
    cg = graph.costs(Cost.TIME)
    for _ in range(3):
        t = time.perf_counter()
        pieces = Pieces.of(graph, cg)
        print(f"{len(segs):,} segments: pieces in {1000 * (time.perf_counter() - t):.0f} ms")
    print(pieces.no_route(0, 0, 1, len(segs) - 1).message)


if __name__ == "__main__":
    main()
