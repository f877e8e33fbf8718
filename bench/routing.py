"""Routing benchmark: ugvmap route queries over HTTP vs ``pgr_dijkstra`` SQL, same run.

    .venv/bin/python bench/routing.py [--pairs 200] [--grid 224] [--grid-pairs 60]

Creates a throwaway database on the configured PostGIS (``DATABASE_URL`` or the embedded
cluster), imports ``../shared/data/osm/andorra.osm.pbf`` with the network importer (if present)
and synthesises a 224×224 grid (99,904 segments, like research/anchors-measured.md §3), then
for each network: p50/p95 of warm HTTP route queries on a one-worker server vs warm
``pgr_dijkstra`` queries on the same edges, costs and node pairs (median of passes), the
ratio, and for the grid the graph build time, memory and the time an edit takes to reach it.
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import httpx
import psycopg

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from app.db.scratch import scratch_database  # noqa: E402
from app.db.session import libpq_dsn, session_scope  # noqa: E402
from app.routing import synthetic  # noqa: E402
from app.routing.costs import Cost, pgrouting_edges_sql  # noqa: E402
from app.routing.graph import RoadGraph  # noqa: E402
from app.routing.live import read_segments, registry  # noqa: E402
from app.settings import get_settings  # noqa: E402
from tests.conftest import running_server  # noqa: E402

OSM = REPO.parent / "shared" / "data" / "osm" / "andorra.osm.pbf"


def percentile(xs: list[float], q: float) -> float:
    """The ``q`` quantile of ``xs`` (nearest rank)."""
    s = sorted(xs)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))]


def node_pairs(conn: psycopg.Connection, net: int, n: int, edges: str) -> list:
    """Random node pairs inside the largest strongly connected component."""
    rows = conn.execute(
        "WITH c AS (SELECT component, node FROM pgr_strongComponents(%s)), "
        "big AS (SELECT component FROM c GROUP BY component ORDER BY count(*) DESC LIMIT 1) "
        "SELECT n.id, ST_X(n.geom), ST_Y(n.geom) FROM c JOIN big USING (component) "
        "JOIN road_nodes n ON n.id = c.node ORDER BY n.id", (edges,)).fetchall()
    rng = random.Random(42)
    return [tuple(rng.sample(rows, 2)) for _ in range(n)]


def time_pass(http: httpx.Client, conn: psycopg.Connection, name: str, edges: str,
              pairs: list) -> tuple[list[float], list[float]]:
    """Time each pair through our HTTP route and through pgr_dijkstra on the same edges."""
    ours, pgr = [], []
    for (a, ax, ay), (b, bx, by) in pairs:
        t = time.perf_counter()
        r = http.get(f"/networks/{name}/route",
                     params={"points": f"{ax!r},{ay!r};{bx!r},{by!r}"})
        ours.append(time.perf_counter() - t)
        assert r.status_code == 200, r.text
        t = time.perf_counter()
        conn.execute("SELECT * FROM pgr_dijkstra(%s, %s::bigint, %s::bigint)",
                     (edges, a, b)).fetchall()
        pgr.append(time.perf_counter() - t)
    return ours, pgr


def http_floor(http: httpx.Client, n: int = 200) -> float:
    """p50 of GET /healthz on the same server: the HTTP stack's share of every request."""
    times = []
    for _ in range(n):
        t = time.perf_counter()
        http.get("/healthz")
        times.append(time.perf_counter() - t)
    return percentile(times, 0.5) * 1e3


def compare(http: httpx.Client, conn: psycopg.Connection, name: str, net: int,
            n_pairs: int, passes: int) -> None:
    """Time both over several passes and print p50/p95 and their ratio."""
    edges = pgrouting_edges_sql(net, Cost.TIME)
    pairs = node_pairs(conn, net, n_pairs, edges)
    time_pass(http, conn, name, edges, pairs[:10])  # warm both sides
    stats = {"ugvmap": {"p50": [], "p95": []}, "pgr": {"p50": [], "p95": []}}
    for _ in range(passes):
        ours, pgr = time_pass(http, conn, name, edges, pairs)
        for key, xs in (("ugvmap", ours), ("pgr", pgr)):
            stats[key]["p50"].append(percentile(xs, 0.5) * 1e3)
            stats[key]["p95"].append(percentile(xs, 0.95) * 1e3)
    med = {k: {q: statistics.median(v) for q, v in d.items()} for k, d in stats.items()}
    segs = conn.execute("SELECT count(*) FROM road_segments WHERE network_id = %s",
                        (net,)).fetchone()[0]
    print(f"\n{name}: {segs} segments, {len(pairs)} OD pairs, cost=time, "
          f"median of {passes} pass(es)")
    print(f"  ugvmap HTTP route   p50 {med['ugvmap']['p50']:8.2f} ms   "
          f"p95 {med['ugvmap']['p95']:8.2f} ms")
    print(f"  pgr_dijkstra SQL    p50 {med['pgr']['p50']:8.2f} ms   "
          f"p95 {med['pgr']['p95']:8.2f} ms")
    print(f"  ratio ugvmap/pgr    p50 {med['ugvmap']['p50'] / med['pgr']['p50']:8.3f}      "
          f"p95 {med['ugvmap']['p95'] / med['pgr']['p95']:8.3f}   (target <= 0.2, goal 0.05)")


def build_figures(url: str, net: int) -> None:
    """Graph build time and memory, and how long an edit takes to reach the graph."""
    dsn = libpq_dsn(url)
    with psycopg.connect(dsn) as conn:
        t0 = time.perf_counter()
        segs, version = read_segments(conn, net)
        t1 = time.perf_counter()
    tracemalloc.start()
    t2 = time.perf_counter()
    graph = RoadGraph(net, version, segs)
    graph.costs(Cost.TIME)
    t3 = time.perf_counter()
    held, _ = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(f"\ngraph of {len(segs)} segments / {graph.n_nodes} nodes: read from PostGIS "
          f"{(t1 - t0) * 1e3:.0f} ms, build arrays + CSR {(t3 - t2) * 1e3:.0f} ms, "
          f"held {held / 2**20:.1f} MiB (arrays built from the rows, time cost model)")
    reg = registry(url)
    reg.get(net, version)
    with psycopg.connect(dsn, autocommit=True) as conn:
        sid = conn.execute("SELECT min(id) FROM road_segments WHERE network_id = %s",
                           (net,)).fetchone()[0]
        lags = []
        for kph in (40, 50, 60, 70, 80):
            t = time.perf_counter()
            conn.execute("UPDATE road_segments SET speed_limit_kph = %s WHERE id = %s",
                         (kph, sid))
            target = conn.execute("SELECT version FROM networks WHERE id = %s",
                                  (net,)).fetchone()[0]
            while reg._graphs[net].version < target:
                time.sleep(0.0005)
            lags.append((time.perf_counter() - t) * 1e3)
    print(f"edit -> graph updated (NOTIFY + bbox patch + CSR rebuild): median "
          f"{statistics.median(lags):.0f} ms over {len(lags)} edits "
          f"(patches {reg.stats['patches']}, full loads {reg.stats['loads']})")


def main() -> None:
    """Benchmark routing on Andorra and on a large synthetic grid."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=200)
    ap.add_argument("--passes", type=int, default=3)
    ap.add_argument("--grid", type=int, default=224, help="grid side (224 -> 99,904 segments)")
    ap.add_argument("--grid-pairs", type=int, default=60)
    args = ap.parse_args()

    with scratch_database("ugvmap_bench") as url, \
            psycopg.connect(libpq_dsn(url), autocommit=True) as conn:
        os.environ["DATABASE_URL"] = url
        get_settings.cache_clear()
        t = time.perf_counter()
        grid_net = synthetic.grid(conn, "grid", args.grid, args.grid)
        print(f"synthesised {args.grid}x{args.grid} grid in {time.perf_counter() - t:.1f} s")
        if OSM.is_file():
            from ingest.network import import_network

            with session_scope(url) as session:
                import_network(session, OSM, "andorra")
            osm_net = conn.execute("SELECT id FROM networks WHERE name = 'andorra'"
                                   ).fetchone()[0]
        else:
            print(f"{OSM} not found: skipping the OSM network")
        build_figures(url, grid_net)
        env = {"DATABASE_URL": url, "UGVMAP_LOG_LEVEL": "WARNING"}
        with running_server(env, workers=1) as base, \
                httpx.Client(base_url=base, timeout=30) as http:
            print(f"\nHTTP floor (GET /healthz, same server) p50 {http_floor(http):.2f} ms")
            if OSM.is_file():
                compare(http, conn, "andorra", osm_net, args.pairs, args.passes)
            compare(http, conn, "grid", grid_net, args.grid_pairs, 1)


if __name__ == "__main__":
    main()
