"""Which point-to-point search for country-size networks: the candidates, measured side by side.

    .venv/bin/python bench/route_search.py --network country [--pairs 20] [--landmarks 8]

Reads a stored network (e.g. the 1M-segment ``country`` that ``bench/routing.py --country``
or ``ugvmap ingest network`` made from :mod:`testkit.synthetic_osm`) and times, on the
same random node pairs under the time cost model, in-process (no HTTP, no snapping):

- ``dijkstra``: scipy's compiled Dijkstra with the growing bound the engine used before;
- ``alt``: A* with ALT landmark bounds (farthest-landmark selection, forward and backward
  landmark distances by scipy), the search loop in pure Python (heapq) — the goal-directed
  prototype; kept here, not in the app, because it is ~10x slower than the hierarchy;
- ``cch``: the customizable contraction hierarchy the app uses (:mod:`app.routing.hierarchy`).

Prints p50/p95 per method, settled nodes for ALT, preprocessing times, and checks that every
method finds the same cost (within the hierarchy's quantum per segment).
"""

from __future__ import annotations

import argparse
import heapq
import random
import sys
import time
from pathlib import Path

import numpy as np
import psycopg
from scipy.sparse.csgraph import dijkstra

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from app.db.session import libpq_dsn  # noqa: E402
from app.routing.costs import Cost  # noqa: E402
from app.routing.geometry import haversine_m  # noqa: E402
from app.routing.graph import RoadGraph  # noqa: E402
from app.routing.live import read_segments  # noqa: E402
from app.settings import get_settings  # noqa: E402
from bench.routing import percentile  # noqa: E402


class Alt:
    """A* with landmark (ALT) lower bounds on one CSR graph."""

    def __init__(self, matrix, n: int, k: int) -> None:
        fwd = matrix[:n, :n].tocsr()
        bwd = fwd.T.tocsr()
        rng = random.Random(1)
        marks = [rng.randrange(n)]
        d_from, d_to = [], []
        for _ in range(k):  # farthest selection: the next landmark is farthest from the rest
            d_from.append(dijkstra(fwd, indices=marks[-1]))
            d_to.append(dijkstra(bwd, indices=marks[-1]))
            far = np.min([np.where(np.isfinite(d), d, 0) for d in d_from], axis=0)
            marks.append(int(np.argmax(far)))
        self.d_from = [tuple(r) for r in np.nan_to_num(np.array(d_from).T, posinf=0.0)]
        self.d_to = [tuple(r) for r in np.nan_to_num(np.array(d_to).T, posinf=0.0)]
        self.indptr, self.indices, self.data = (fwd.indptr.tolist(), fwd.indices.tolist(),
                                                fwd.data.tolist())

    def route(self, s: int, t: int) -> tuple[float, int]:
        """(cost, settled nodes)."""
        df_t, dt_t = self.d_from[t], self.d_to[t]
        d_from, d_to = self.d_from, self.d_to

        def h(v: int) -> float:
            fv, tv = d_from[v], d_to[v]
            return max(max(a - b for a, b in zip(df_t, fv, strict=True)),
                       max(a - b for a, b in zip(tv, dt_t, strict=True)), 0.0)

        dist = {s: 0.0}
        heap = [(h(s), s)]
        done = set()
        indptr, indices, data = self.indptr, self.indices, self.data
        while heap:
            _, v = heapq.heappop(heap)
            if v in done:
                continue
            if v == t:
                return dist[v], len(done)
            done.add(v)
            dv = dist[v]
            for k in range(indptr[v], indptr[v + 1]):
                w, nd = indices[k], dv + data[k]
                if nd < dist.get(w, np.inf):
                    dist[w] = nd
                    heapq.heappush(heap, (nd + h(w), w))
        return np.inf, len(done)


def main() -> None:
    """Time every search on the same pairs and print one row per method."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--network", default="country")
    ap.add_argument("--pairs", type=int, default=20)
    ap.add_argument("--landmarks", type=int, default=8)
    args = ap.parse_args()
    with psycopg.connect(libpq_dsn(get_settings().database_url), autocommit=True) as conn:
        net = conn.execute("SELECT id FROM networks WHERE name = %s",
                           (args.network,)).fetchone()[0]
        segs, version = read_segments(conn, net)
    graph = RoadGraph(net, version, segs)
    cg = graph.costs(Cost.TIME)
    n = graph.n_nodes
    print(f"{args.network}: {len(segs)} segments, {n} nodes")
    t = time.perf_counter()
    cg.hierarchy.ready.wait()
    while cg.hierarchy.metric(cg.hierarchy_key, cg.version, cg.arc_costs, cg.max_rate) is None:
        time.sleep(0.05)
    metric = cg.hierarchy.metric(cg.hierarchy_key, cg.version, cg.arc_costs, cg.max_rate)
    print(f"cch preprocessing (topology + customisation): {time.perf_counter() - t:.1f} s")
    t = time.perf_counter()
    alt = Alt(cg.matrix, n, args.landmarks)
    print(f"alt preprocessing ({args.landmarks} landmarks, both directions): "
          f"{time.perf_counter() - t:.1f} s")

    full = dijkstra(cg.matrix[:n, :n].tocsr(), indices=0)
    reachable = np.flatnonzero(np.isfinite(full))
    rng = random.Random(42)
    pairs = [tuple(rng.sample(reachable.tolist(), 2)) for _ in range(args.pairs)]
    times: dict[str, list[float]] = {"dijkstra": [], "alt": [], "cch": []}
    settled = []
    for s, t_ in pairs:
        t0 = time.perf_counter()
        lonlat = cg.hierarchy.node_lonlat  # the engine's first bound, then growing
        limit, d = 2 * haversine_m(lonlat[s], lonlat[t_]) / cg.max_rate + 1.0, np.inf
        while True:
            dist, _ = cg.search([(s, 0.0)], limit=limit)
            if dist[t_] <= limit or limit > cg.total_cost:
                d = dist[t_]
                break
            limit *= 3
        times["dijkstra"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        d_alt, k = alt.route(s, t_)
        times["alt"].append(time.perf_counter() - t0)
        settled.append(k)
        t0 = time.perf_counter()
        _, _, arcs = metric.shortest(cg.version, [(s, 0.0)], [(t_, 0.0)])
        d_cch = float(cg.arc_costs[arcs].sum())
        times["cch"].append(time.perf_counter() - t0)
        assert abs(d_alt - d) <= 1e-6 * d, (s, t_, d_alt, d)
        assert -1e-6 * d <= d_cch - d <= metric.quantum * len(arcs) + 1e-6 * d, (d_cch, d)
    base = percentile(times["dijkstra"], 0.5)
    for name, xs in times.items():
        print(f"  {name:9s} p50 {percentile(xs, 0.5) * 1e3:9.2f} ms   p95 "
              f"{percentile(xs, 0.95) * 1e3:9.2f} ms   ratio to dijkstra p50 "
              f"{percentile(xs, 0.5) / base:6.3f}")
    print(f"  alt settled nodes p50 {percentile(settled, 0.5):.0f} of {n}")


if __name__ == "__main__":
    main()
