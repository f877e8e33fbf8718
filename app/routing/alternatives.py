"""Alternative routes (OSRM's ``alternatives=true|N``) by the penalty method.

After the best route, the cost of every segment on a route found so far is raised by
:data:`PENALTY` of its cost per use and the search runs again, so the next route prefers other
roads where they cost little more. A found route is kept as an alternative only when, at its
true cost, it is at most :data:`MAX_STRETCH` dearer than the best and shares at most
:data:`MAX_SHARE` of its length with every route kept before (clearly different, not the same
road with a detour at one junction). The penalised searches are plain bounded Dijkstra on a
re-weighted copy of the cost graph (the hierarchy holds only true costs), so each alternative
costs a few searches; they are offered for two-point routes, as OSRM does.

Known limit: the cost graph keeps one arc per pair of junctions (the cheapest), so two roads
that join the same two junctions directly, with no node between, are never alternatives to
each other.

Why this rather than the plateau method: the plateau method needs a full forward and
backward search tree per request, which the hierarchy does not give; the penalty method
reuses the engine's searches unchanged and produces the same kind of answers on road
networks (Bader et al., 2011, "Alternative route graphs in road networks").
"""

from __future__ import annotations

import dataclasses
import threading
from collections import defaultdict

import numpy as np

from app.errors import NoRouteError
from app.routing.engine import Leg, Router
from app.routing.graph import CostGraph, RoadGraph
from app.routing.snap import Snap

PENALTY = 0.5
MAX_STRETCH = 0.25
MAX_SHARE = 0.75
ROUNDS_PER_ALTERNATIVE = 3


def penalised(cg: CostGraph, factor: np.ndarray) -> CostGraph:
    """A copy of ``cg`` with each segment's cost multiplied by ``factor[row]`` (no hierarchy;
    its own Dijkstra matrix, built on first use from the penalised arc weights)."""
    f = np.append(factor[cg.arcs.row], np.ones(cg.SLOTS))
    return dataclasses.replace(
        cg, seg_cost=cg.seg_cost * factor, weights=cg.weights * f, lock=threading.Lock(),
        hierarchy=None, _matrix=None,
        total_cost=cg.total_cost * float(factor.max(initial=1.0)))


def _metres(graph: RoadGraph, leg: Leg) -> dict[int, float]:
    """Metres driven per segment row."""
    out: dict[int, float] = defaultdict(float)
    for p in leg.pieces:
        out[p.row] += abs(p.f_to - p.f_from) * float(graph.segs.length_m[p.row])
    return out


def _share(a: dict[int, float], b: dict[int, float]) -> float:
    """Share of route ``a``'s length also driven by ``b``."""
    total = sum(a.values())
    if total <= 0:
        return 1.0
    return sum(min(m, b.get(row, 0.0)) for row, m in a.items()) / total


def alternatives(graph: RoadGraph, cg: CostGraph, snaps: list[Snap], best: Leg,
                 n: int) -> list[Leg]:
    """Up to ``n`` clearly different alternatives to ``best`` (from snaps[0] to snaps[1]),
    cheapest first."""
    used = np.zeros(len(graph.segs))
    kept = [_metres(graph, best)]
    found: list[Leg] = []
    for row in kept[0]:
        used[row] += 1
    for _ in range(ROUNDS_PER_ALTERNATIVE * n):
        if len(found) == n:
            break
        try:
            leg = Router(graph, penalised(cg, 1.0 + PENALTY * used), snaps).leg(0, 1)
        except NoRouteError:
            break
        metres = _metres(graph, leg)
        for row in metres:
            used[row] += 1
        weight = float((np.abs(leg.f_to - leg.f_from) * cg.seg_cost[leg.rows]).sum())
        if weight > (1.0 + MAX_STRETCH) * best.weight:
            continue
        if any(_share(metres, other) > MAX_SHARE for other in kept):
            continue
        kept.append(metres)
        found.append(dataclasses.replace(leg, weight=weight))
    return sorted(found, key=lambda leg: leg.weight)
