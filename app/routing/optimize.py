"""Best visiting order of task points: a path with both ends fixed (``optimize=true``), and
OSRM's trips (a round trip, or an open trip with one or both ends fixed).

Exact (Held–Karp dynamic programme, O(2^k·k²)) up to :data:`EXACT_MAX` intermediate points;
beyond that nearest-neighbour construction improved by 2-opt, which on road-like metrics is
typically within a few percent of optimal and runs in milliseconds for a hundred points (each
move's gain in O(1) from prefix sums, all moves from one position at once). Costs are
asymmetric (one-way streets), which both methods respect. Every trip is solved as such a path
on a matrix with one extra row or column, as OSRM does with its table (``trip.cpp``): a round
trip ends at a copy of its start, an open end is a free dummy point.
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
            o = np.array(order)
            ahead = np.concatenate([[0.0], np.cumsum(cost[o[:-1], o[1:]])])
            back = np.concatenate([[0.0], np.cumsum(cost[o[1:], o[:-1]])])
            j = np.arange(i + 1, n - 1)  # reverse order[i..j]
            gain = (cost[o[i - 1], o[i]] + cost[o[j], o[j + 1]] + ahead[j] - ahead[i]
                    - cost[o[i - 1], o[j]] - cost[o[i], o[j + 1]] - (back[j] - back[i]))
            best = int(np.argmax(gain))
            if gain[best] > 1e-9:
                k = int(j[best])
                order = order[:i] + order[i:k + 1][::-1] + order[k + 1:]
                improved = True
    return order


def best_order(cost: np.ndarray) -> list[int]:
    """Visiting order (indices into ``cost``), starting at 0 and ending at n-1."""
    if len(cost) - 2 <= EXACT_MAX:
        return held_karp(cost)
    return nearest_neighbour_2opt(cost)


FORBIDDEN = 1e15  # a cost no order takes while any other exists (finite: gains stay numbers)


def trip_order(cost: np.ndarray, roundtrip: bool, fixed_start: bool, fixed_end: bool
               ) -> list[int]:
    """The order to visit all points (a round trip's return to its start is implied), as
    OSRM's trip: a round trip starts at the first point, or at the last when only the
    destination is fixed (``destination=last``); with both fixed it runs first .. last and
    then back. An open trip starts at the first and/or ends at the last point."""
    n = len(cost)
    last = n - 1
    if roundtrip and not (fixed_start and fixed_end):
        start = last if fixed_end else 0
        others = [i for i in range(n) if i != start]
        index = [start, *others, start]  # a path from the start back to a copy of it
        path = best_order(cost[np.ix_(index, index)])
        return [index[k] for k in path[:-1]]
    if fixed_start and fixed_end:
        return best_order(cost) if n > 1 else [0]
    padded = np.zeros((n + 1, n + 1))
    if fixed_start:  # ends anywhere: a free dummy end after every point
        padded[:n, :n] = cost
        padded[n, :] = FORBIDDEN
        return best_order(padded)[:-1]
    padded[1:, 1:] = cost  # starts anywhere: a free dummy start (index 0) before every point
    padded[1:, 0] = FORBIDDEN
    return [k - 1 for k in best_order(padded)[1:]]
