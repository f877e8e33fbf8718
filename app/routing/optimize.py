"""Best visiting order of the intermediate task points, first and last fixed.

Exact (Held–Karp dynamic programme, O(2^k·k²)) up to :data:`EXACT_MAX` intermediate points;
beyond that nearest-neighbour construction improved by 2-opt, which on road-like metrics is
typically within a few percent of optimal and runs in milliseconds for a hundred points.
Costs are asymmetric (one-way streets), which both methods respect.
"""

from __future__ import annotations

import itertools

import numpy as np

EXACT_MAX = 10


def path_cost(cost: np.ndarray, order: list[int]) -> float:
    """Total cost of visiting the points in ``order``."""
    return float(sum(cost[a, b] for a, b in itertools.pairwise(order)))


def held_karp(cost: np.ndarray) -> list[int]:
    """Optimal path 0 -> (all of 1..n-2 in some order) -> n-1."""
    n = len(cost)
    mids = list(range(1, n - 1))
    k = len(mids)
    if k == 0:
        return [0, n - 1]
    full = 1 << k
    best = np.full((full, k), np.inf)
    parent = np.full((full, k), -1, dtype=np.int64)
    for j in range(k):
        best[1 << j, j] = cost[0, mids[j]]
    for mask in range(1, full):
        for j in range(k):
            here = best[mask, j]
            if not (mask >> j) & 1 or not np.isfinite(here):
                continue
            for t in range(k):
                if (mask >> t) & 1:
                    continue
                nxt, c = mask | (1 << t), here + cost[mids[j], mids[t]]
                if c < best[nxt, t]:
                    best[nxt, t], parent[nxt, t] = c, j
    ends = best[full - 1] + cost[mids, n - 1]
    j, mask, rev = int(np.argmin(ends)), full - 1, []
    while j >= 0:
        rev.append(mids[j])
        j, mask = int(parent[mask, j]), mask & ~(1 << j)
    return [0, *rev[::-1], n - 1]


def nearest_neighbour_2opt(cost: np.ndarray) -> list[int]:
    """Greedy path from 0 over the middle points to n-1, then 2-opt until no gain."""
    n = len(cost)
    left, order = set(range(1, n - 1)), [0]
    while left:
        nxt = min(left, key=lambda j: cost[order[-1], j])
        order.append(nxt)
        left.remove(nxt)
    order.append(n - 1)
    improved = True
    while improved:
        improved = False
        for i in range(1, n - 2):
            for j in range(i + 1, n - 1):
                candidate = order[:i] + order[i:j + 1][::-1] + order[j + 1:]
                if path_cost(cost, candidate) < path_cost(cost, order) - 1e-9:
                    order, improved = candidate, True
    return order


def best_order(cost: np.ndarray) -> list[int]:
    """Visiting order (indices into ``cost``), starting at 0 and ending at n-1."""
    if len(cost) - 2 <= EXACT_MAX:
        return held_karp(cost)
    return nearest_neighbour_2opt(cost)
