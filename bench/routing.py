"""Routing benchmark: ugvmap route queries over HTTP vs ``pgr_dijkstra`` SQL, same run.

    .venv/bin/python bench/routing.py [--pairs 200] [--grid 224] [--grid-pairs 60]
    .venv/bin/python bench/routing.py --country [--side 810] [--country-pairs 20]

``--country`` adds the 1M-segment run (~10 min, ~3 GiB peak across processes): a synthetic
country network (:mod:`testkit.synthetic_osm`, 810 x 810 intersections) imported with
``ugvmap ingest network`` in a child process (wall time and the child's peak RSS), graph and
hierarchy build time and memory (topology by nested dissection, then again from the order it
saved, as a restart does), route p50/p95 vs ``pgr_dijkstra`` on the same pairs, the time from
an edit (SQL UPDATE, or API PATCH of speed, lanes, class, one-way, geometry) to the next route
that reflects it, and what a split and a merge (arcs change) do to routes.

Creates a throwaway database on the configured PostGIS (``DATABASE_URL`` or the embedded
cluster), imports ``../shared/data/osm/andorra.osm.pbf`` with the network importer (if present)
and synthesises a 224×224 grid (99,904 segments, like research/anchors-measured.md §3), then
for each network: p50/p95 of HTTP route queries on a one-worker server (timed through the
standard library's HTTP client, :class:`Wire`) vs ``pgr_dijkstra`` queries on the same edges,
costs and node pairs (median of passes), the ratio, each side in a row (its steady state) and
cold (each HTTP request right after a ``pgr_dijkstra``), the CPU per request, and for the grid
the graph build time, memory and the time an edit takes to reach it.
"""

from __future__ import annotations

import argparse
import gc
import gzip
import http.client
import itertools
import json
import math
import os
import random
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import urlencode, urlsplit

import httpx
import numpy as np
import polyline
import psycopg

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from app.db.session import libpq_dsn, session_scope  # noqa: E402
from app.routing.costs import Cost, pgrouting_edges_sql  # noqa: E402
from app.routing.graph import RoadGraph  # noqa: E402
from app.routing.hierarchy import Hierarchy  # noqa: E402
from app.routing.live import read_segments, registry  # noqa: E402
from app.settings import get_settings  # noqa: E402
from testkit import synthetic  # noqa: E402
from testkit.network_helpers import node_pairs  # noqa: E402
from testkit.scratch import scratch_database  # noqa: E402
from testkit.server import running_server  # noqa: E402

OSM = REPO.parent / "shared" / "data" / "osm" / "andorra.osm.pbf"


def percentile(xs: list[float], q: float) -> float:
    """The ``q`` quantile of ``xs`` (nearest rank)."""
    s = sorted(xs)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))]


OURS, OSRM_URL, PGR = "/route (our defaults)", "/route/v1 (OSRM's defaults)", "pgr_dijkstra SQL"
# Issue 23's goals, route p50 over HTTP to pgr_dijkstra's on the same pairs in the same run, as
# each side's p50 in its steady state (MODES[False]); the cold order is printed beside them.
GOALS = {"andorra": {OSRM_URL: 0.3, OURS: 0.5}, "grid": {OSRM_URL: 0.05, OURS: 0.05},
         "country": {OSRM_URL: 0.01, OURS: 0.01}}


class Wire:
    """GETs on one kept-alive connection of the standard library's HTTP client, for the timed
    loops. Why not httpx, used for everything else here: its own work per request (0.23 ms
    against a server that answers fixed bytes, 0.05 ms with ``http.client``; more when the box
    is busy) would be counted as the server's, while pgr_dijkstra is timed through psycopg's
    C client."""

    def __init__(self, base: str) -> None:
        parts = urlsplit(base)
        self.conn = http.client.HTTPConnection(parts.hostname or "", parts.port, timeout=60)

    def get(self, path: str, params: dict[str, str] | None = None) -> tuple[int, bytes]:
        """Status and body of a GET, asking for gzip as httpx and browsers do (the server's
        compression and the client's decompression are part of what is timed). A connection
        the server closed after its keep-alive timeout (5 s idle: the 1M network's
        pgr_dijkstra calls in a row take longer) is opened again once, as clients do."""
        target = f"{path}?{urlencode(params)}" if params else path
        for retry in (False, True):
            try:
                self.conn.request("GET", target, headers={"Accept-Encoding": "gzip"})
                response = self.conn.getresponse()
                break
            except (http.client.RemoteDisconnected, ConnectionResetError, BrokenPipeError):
                self.conn.close()
                if retry:
                    raise
        body = response.read()
        if response.getheader("Content-Encoding") == "gzip":
            body = gzip.decompress(body)
        return response.status, body


def requests(wire: Wire, conn: psycopg.Connection, name: str, edges: str
             ) -> dict[str, Callable[[tuple, tuple], Any]]:
    """The three requests each pair of nodes ((id, lon, lat), twice) is timed with: our HTTP
    route with our URL's defaults (GeoJSON, full overview, steps), OSRM's URL with OSRM's
    (polyline, simplified, no steps), and pgr_dijkstra on the same edges."""
    def ours(a: tuple, b: tuple) -> tuple[int, bytes]:
        return wire.get(f"/networks/{name}/route",
                        {"points": f"{a[1]!r},{a[2]!r};{b[1]!r},{b[2]!r}", "cost": "time"})

    def osrm(a: tuple, b: tuple) -> tuple[int, bytes]:
        return wire.get(f"/networks/{name}/route/v1/driving/{a[1]!r},{a[2]!r};{b[1]!r},{b[2]!r}")

    def pgr(a: tuple, b: tuple) -> list:
        return conn.execute("SELECT agg_cost FROM pgr_dijkstra(%s, %s::bigint, %s::bigint) "
                            "ORDER BY seq", (edges, a[0], b[0])).fetchall()

    return {OURS: ours, OSRM_URL: osrm, PGR: pgr}


def _timed(call: Callable[[tuple, tuple], Any], a: tuple, b: tuple) -> tuple[float, Any]:
    """Seconds one request took, and its answer."""
    t = time.perf_counter()
    answer = call(a, b)
    return time.perf_counter() - t, answer


MODES = {
    False: "in a row (each side's requests back to back: its steady state, as a burst of "
           "queries from a planner sees it)",
    True: "cold (each HTTP request right after a pgr_dijkstra of the same pair: a server idle "
          "for ~5 ms, as a planner's one route before departure finds it; printed beside the "
          "goals, which are steady-state p50s: see docs/performance.md, a sixth round)",
}


def time_pass(wire: Wire, conn: psycopg.Connection, name: str, edges: str, pairs: list,
              cold: bool) -> tuple[dict[str, list[float]], list[float]]:
    """Time every pair through the three :func:`requests`, in one of two orders (``MODES``):
    each side's in a row, or ``cold``, pgr_dijkstra, our URL, pgr_dijkstra, OSRM's URL for each
    pair, so both HTTP requests meet a server PostgreSQL's work left idle. On this virtual
    machine work after ~5 ms of idling runs up to twice as slowly (caches cold, CPUs woken at
    each hop), which an HTTP request of several hops pays more than one SQL round trip; both
    orders are printed. (Until 2026-11-27 one interleaved order, pgr_dijkstra, our URL, OSRM's
    URL, was the headline: OSRM's URL found the server warm after ours.) Compare the answers:
    the relative difference of each route's cost (our ``weight``, the last ``agg_cost`` of
    pgr_dijkstra), so every figure is of routes known to be equal."""
    calls = requests(wire, conn, name, edges)
    schedule = ([(key, pair) for pair in pairs for key in (PGR, OURS, PGR, OSRM_URL)] if cold
                else [(key, pair) for key in (OURS, OSRM_URL, PGR) for pair in pairs])
    times: dict[str, list[float]] = {key: [] for key in calls}
    answers: dict[str, list[Any]] = {key: [] for key in calls}
    for key, (a, b) in schedule:
        seconds, answer = _timed(calls[key], a, b)
        times[key].append(seconds)
        answers[key].append(answer)
    expected = [float(rows[-1][0]) for rows in answers[PGR][::2 if cold else 1]]
    diffs = []
    for key in (OURS, OSRM_URL):
        for (status, body), cost in zip(answers[key], expected, strict=True):
            assert status == 200, body
            got = json.loads(body)["routes"][0]["weight"]
            diffs.append(abs(float(got) - cost) / max(cost, 1e-9))
    return times, diffs


def http_floor(wire: Wire, n: int = 200) -> float:
    """p50 of GET /healthz on the same server: the HTTP stack's share of every request."""
    times = []
    for _ in range(n):
        t = time.perf_counter()
        wire.get("/healthz")
        times.append(time.perf_counter() - t)
    return percentile(times, 0.5) * 1e3


def compare(http: httpx.Client, conn: psycopg.Connection, base: str, name: str, net: int,
            n_pairs: int, passes: int) -> list:
    """Time both over several passes in each of ``MODES`` and print p50/p95 and their
    ratios, then the CPU per request; the pairs."""
    edges = pgrouting_edges_sql(net, Cost.TIME)
    pairs = node_pairs(conn, net, n_pairs, edges)
    # Warm both sides: every pair once through ours (the first request of a network loads its
    # graph), a few through pgr_dijkstra (each of its calls reads the whole edge table anyway,
    # cached after the first).
    wire = Wire(base)
    time_pass(wire, conn, name, edges, pairs[:3], cold=False)
    for (_, ax, ay), (_, bx, by) in pairs:
        http.get(f"/networks/{name}/route",
                 params={"points": f"{ax!r},{ay!r};{bx!r},{by!r}", "cost": "time"})
    segs = conn.execute("SELECT count(*) FROM road_segments WHERE network_id = %s",
                        (net,)).fetchone()[0]
    print(f"\n{name}: {segs} segments, {len(pairs)} OD pairs, cost=time, "
          f"median of {passes} pass(es)")
    diffs: list[float] = []
    for cold, mode in MODES.items():
        stats: dict[str, dict[str, list[float]]] = {k: {"p50": [], "p95": []}
                                                    for k in (OURS, OSRM_URL, PGR)}
        for _ in range(passes):
            times, pass_diffs = time_pass(wire, conn, name, edges, pairs, cold)
            diffs += pass_diffs
            for key, xs in times.items():
                stats[key]["p50"].append(percentile(xs, 0.5) * 1e3)
                stats[key]["p95"].append(percentile(xs, 0.95) * 1e3)
        med = {k: {q: statistics.median(v) for q, v in d.items()} for k, d in stats.items()}
        print(f"  {mode}")
        for key in (OURS, OSRM_URL, PGR):
            print(f"    {key:30s} p50 {med[key]['p50']:8.2f} ms   p95 {med[key]['p95']:8.2f} ms")
        for key in (OURS, OSRM_URL):
            ratio = med[key]['p50'] / med[PGR]['p50']
            goal = GOALS.get(name, {}).get(key) if not cold else None
            verdict = "" if goal is None else \
                f"   goal <= {goal:g}: {'met' if ratio <= goal else 'MISSED'}"
            print(f"    ratio {key:24s} p50 {ratio:8.3f}      "
                  f"p95 {med[key]['p95'] / med[PGR]['p95']:8.3f}   (to pgr_dijkstra, same run)"
                  f"{verdict}")
    # The hierarchy rounds costs to whole units (a few 1e-5 s per segment): 1e-4 relative.
    equal = sum(d <= 1e-4 for d in diffs)
    print(f"  routes equal to pgr_dijkstra (cost within 1e-4): {equal}/{len(diffs)}, "
          f"max relative difference {max(diffs):.2e}")
    assert equal == len(diffs), "a route differs from pgr_dijkstra"
    cpu_per_request(http, conn, base, name, edges, pairs)
    return pairs


def _cpu_s(pids: list[int]) -> float:
    """CPU seconds (user + system) the processes ``pids`` have used so far."""
    return sum(_ticks(Path(f"/proc/{pid}/stat")) for pid in pids) / os.sysconf("SC_CLK_TCK")


def _ticks(stat: Path) -> int:
    """User + system clock ticks of a process or thread (0 once it has ended)."""
    try:
        fields = stat.read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0
    return int(fields[11]) + int(fields[12])


def _cpu_parts(pids: list[int]) -> dict[str, float]:
    """CPU seconds so far of the server's event-loop thread (its main thread), its other
    threads (the thread pool, the change listener) and its database backends (``pids``: the
    server, then the backends, as :func:`server_pids` lists them)."""
    server, backends = pids[0], pids[1:]
    tick = os.sysconf("SC_CLK_TCK")
    tasks = {t.name: _ticks(t / "stat") for t in Path(f"/proc/{server}/task").iterdir()}
    loop = tasks.pop(str(server), 0)
    return {"event loop": loop / tick, "other threads": sum(tasks.values()) / tick,
            "database": _cpu_s(backends)}


def server_pids(base: str, conn: psycopg.Connection) -> list[int]:
    """The server process listening at ``base`` and the database backends of its
    connections (its version reads and the change listener)."""
    port = base.rsplit(":", 1)[1]
    ours = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit()
            and f"--port\x00{port}\x00" in _cmdline(p)]
    backends = [row[0] for row in conn.execute(
        "SELECT pid FROM pg_stat_activity WHERE datname = current_database() "
        "AND pid <> pg_backend_pid() AND backend_type = 'client backend'").fetchall()]
    return ours + backends


def _cmdline(proc: Path) -> str:
    try:
        return (proc / "cmdline").read_bytes().decode(errors="replace")
    except OSError:
        return ""


# Our requests are timed this many times over the pairs: /proc counts CPU in 10 ms ticks,
# 0.1 ms per request over a hundred pairs. pgr_dijkstra's, milliseconds to seconds, once.
CPU_ROUNDS = 3


def cpu_per_request(http: httpx.Client, conn: psycopg.Connection, base: str, name: str,
                    edges: str, pairs: list) -> None:
    """CPU milliseconds per request, of the server and the database backends it uses, against
    the CPU of the backend that runs pgr_dijkstra: unlike wall time, it does not count the
    waits for a CPU that other jobs on a shared box add to every hop (HTTP, thread pool,
    database) a request makes, so it is steadier from run to run. Ours is split into the
    server's event-loop thread, its other threads and its database backends: where a
    request's CPU goes."""
    ours = server_pids(base, conn)
    mine = [conn.execute("SELECT pg_backend_pid()").fetchone()[0]]
    urls = {
        OURS: lambda a, b: (f"/networks/{name}/route",
                            {"points": f"{a[1]!r},{a[2]!r};{b[1]!r},{b[2]!r}"}),
        OSRM_URL: lambda a, b: (f"/networks/{name}/route/v1/driving/"
                                f"{a[1]!r},{a[2]!r};{b[1]!r},{b[2]!r}", {}),
    }
    cpu, parts = {}, {}
    n = len(pairs) * CPU_ROUNDS
    for key, url in urls.items():
        before, split = _cpu_s(ours), _cpu_parts(ours)
        for a, b in pairs * CPU_ROUNDS:
            path, params = url(a, b)
            http.get(path, params=params)
        cpu[key] = (_cpu_s(ours) - before) / n * 1e3
        parts[key] = {part: (seconds - split[part]) / n * 1e3
                      for part, seconds in _cpu_parts(ours).items()}
    before = _cpu_s(mine)
    for a, b in pairs:
        conn.execute("SELECT agg_cost FROM pgr_dijkstra(%s, %s::bigint, %s::bigint)",
                     (edges, a[0], b[0])).fetchall()
    cpu[PGR] = (_cpu_s(mine) - before) / len(pairs) * 1e3
    for key in (OURS, OSRM_URL, PGR):
        print(f"  CPU per request {key:30s} {cpu[key]:7.2f} ms"
              + (f"   ratio {cpu[key] / cpu[PGR]:6.3f}   ("
                 + ", ".join(f"{part} {ms:.2f}" for part, ms in parts[key].items()) + ")"
                 if key != PGR else ""))


def _p50_ms(call, runs: int) -> float:
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        call()
        times.append(time.perf_counter() - t)
    return statistics.median(times) * 1e3


def table_and_match(http: httpx.Client, name: str, pairs: list, runs: int = 7) -> None:
    """Table of 100 x 100 points and the match of a 1,000-point trace, on one network."""
    pts = [(x, y) for pair in pairs for _, x, y in pair][:100]
    coords = ";".join(f"{x!r},{y!r}" for x, y in pts)
    for wanted in ("duration", "duration,distance"):
        def table(wanted: str = wanted) -> None:
            r = http.get(f"/networks/{name}/table/v1/driving/{coords}",
                         params={"annotations": wanted})
            assert r.status_code == 200, r.text
        table()
        print(f"  table {len(pts)} x {len(pts)} (annotations={wanted}): p50 "
              f"{_p50_ms(table, runs):.1f} ms over {runs} runs   (goal < 100 ms)")
    trace, driven = _trace(http, name, pts, 1000)
    encoded = polyline.encode([(y, x) for x, y in trace], 6)
    stamps = ";".join(str(2 * k) for k in range(len(trace)))
    answers: dict[str, dict] = {}
    for label, params in (("OSRM's defaults", {}),
                          ("steps, full GeoJSON", {"steps": "true", "overview": "full",
                                                   "geometries": "geojson"})):
        def matched(params: dict = params, label: str = label) -> None:
            r = http.get(f"/networks/{name}/match/v1/driving/polyline6({encoded})",
                         params={"timestamps": stamps, **params})
            assert r.status_code == 200, r.text
            answers[label] = r.json()
        matched()
        print(f"  match of a {len(trace)}-point trace ({label}): p50 "
              f"{_p50_ms(matched, 3):.0f} ms over 3 runs   (goal < 1 s)")
    body = answers["OSRM's defaults"]
    found = {s["id"] for m in body["matchings"] for leg in m["legs"] for s in leg["segments"]}
    print(f"    {len(body['matchings'])} matching(s), "
          f"{sum(t is not None for t in body['tracepoints'])} points matched, "
          f"{len(found & driven) / len(driven):.1%} of the driven segments recovered")


def _trace(http: httpx.Client, name: str, pts: list, n: int) -> tuple[list, set[int]]:
    """A GNSS-like trace of ``n`` points along routes through ``pts`` (every ~15 m, 4 m of
    noise), and the segments those routes drive."""
    rng = random.Random(3)
    line: list[list[float]] = []
    driven: set[int] = set()
    for a, b in itertools.pairwise(pts):
        r = http.get(f"/networks/{name}/route/v1/driving/{a[0]!r},{a[1]!r};{b[0]!r},{b[1]!r}",
                     params={"overview": "full", "geometries": "geojson"}).json()
        line += r["routes"][0]["geometry"]["coordinates"]
        driven |= {s["id"] for leg in r["routes"][0]["legs"] for s in leg["segments"]}
        if len(line) > 3 * n:
            break
    xy = np.array(line)
    m_per_deg = np.array([111_320 * math.cos(math.radians(xy[0, 1])), 111_320])
    step = np.hypot(*((np.diff(xy, axis=0)) * m_per_deg).T)
    along = np.concatenate([[0.0], np.cumsum(step)])
    at = np.linspace(0, along[-1], n)
    trace = [(float(np.interp(s, along, xy[:, 0])) + rng.gauss(0, 4) / m_per_deg[0],
              float(np.interp(s, along, xy[:, 1])) + rng.gauss(0, 4) / m_per_deg[1])
             for s in at]
    return trace, driven


def rss_mib() -> float:
    """This process's resident memory now (MiB): counts RoutingKit's C++ allocations too."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def build_figures(url: str, net: int, edits: bool = True) -> None:
    """Graph build time and memory, and how long an edit takes to reach the graph."""
    dsn = libpq_dsn(url)
    with psycopg.connect(dsn) as conn:
        t0 = time.perf_counter()
        segs, version = read_segments(conn, net)
        t1 = time.perf_counter()
    tracemalloc.start()
    t2 = time.perf_counter()
    graph = RoadGraph(net, version, segs)
    cg = graph.costs(Cost.TIME)
    t3 = time.perf_counter()
    held, _ = tracemalloc.get_traced_memory()
    cg.search([(0, 0.0)], limit=0.0)  # builds Dijkstra's CSR, which edits only need lazily
    t4 = time.perf_counter()
    with_csr, _ = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(f"\ngraph of {len(segs)} segments / {graph.n_nodes} nodes: read from PostGIS "
          f"{(t1 - t0) * 1e3:.0f} ms, build arrays + arc table + time weights "
          f"{(t3 - t2) * 1e3:.0f} ms, held {held / 2**20:.1f} MiB; Dijkstra CSR on first use "
          f"+{(t4 - t3) * 1e3:.0f} ms, +{(with_csr - held) / 2**20:.1f} MiB")
    h = cg.hierarchy
    if h is not None:
        before = rss_mib()
        t4 = time.perf_counter()
        h.ready.wait()
        t5 = time.perf_counter()
        while h.metric(cg.hierarchy_key, cg.version, cg.arc_costs, cg.max_rate) is None:
            time.sleep(0.05)
        t6 = time.perf_counter()
        print(f"contraction hierarchy (background thread): topology {t5 - t4:.1f} s "
              f"({h.order_source} order), first customisation {t6 - t5:.1f} s, "
              f"RSS +{rss_mib() - before:.0f} MiB")
        again = Hierarchy(h.arcs, h.node_lonlat, h.node_ids)
        t7 = time.perf_counter()
        again.build()
        print(f"  the same topology from the order saved in the data dir (restart, second "
              f"worker): {time.perf_counter() - t7:.1f} s ({again.order_source} order)")
        del again
    del graph, cg
    if not edits:
        return
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
    print(f"edit -> graph updated (NOTIFY + bbox re-read + row patch): median "
          f"{statistics.median(lags):.0f} ms over {len(lags)} edits "
          f"(patches {reg.stats['patches']}, full loads {reg.stats['loads']})")


def wait_for_hierarchy(http: httpx.Client, name: str, pair: tuple, timeout_s: float = 120
                       ) -> str:
    """Poll one long route until it is answered 2.5x faster than right after the graph
    loaded (Dijkstra then): the server's hierarchy is built. Says how long that took. With a
    contraction order saved by an earlier build the hierarchy can be ready before the first
    timed answer; then no drop comes, and the wait ends at ``timeout_s`` saying so."""
    (_, ax, ay), (_, bx, by) = pair
    params = {"points": f"{ax!r},{ay!r};{bx!r},{by!r}"}

    def timed() -> float:
        t = time.perf_counter()
        assert http.get(f"/networks/{name}/route", params=params).status_code == 200
        return time.perf_counter() - t

    t0 = time.perf_counter()
    timed()  # loads the graph
    first = timed()
    while time.perf_counter() - t0 < timeout_s:
        if timed() < first / 2.5:
            return f"after {time.perf_counter() - t0:.0f} s"
        time.sleep(1.0)
    return (f"not detected within {timeout_s:.0f} s: no drop in route time (ready from the "
            "start from a saved order, or not built: timings may include Dijkstra answers)")


def _settle(http: httpx.Client, name: str, params: dict, fast_ms: float) -> None:
    """Wait until the route is answered about as fast as before any edit: the previous edit has
    reached the hierarchy, so each edit is timed from a quiet state (at most 60 s)."""
    deadline = time.perf_counter() + 60
    while time.perf_counter() < deadline:
        t = time.perf_counter()
        http.get(f"/networks/{name}/route", params=params)
        if (time.perf_counter() - t) * 1e3 <= 2 * fast_ms + 5:
            return
        time.sleep(0.2)


def _lag(http: httpx.Client, name: str, params: dict, fast_ms: float, edit, seen
         ) -> tuple[float, float]:
    """Milliseconds from the start of ``edit()`` to a route response for which ``seen(body)``
    holds, and of that the edit call itself (the database write with its triggers, or the
    PATCH); the route is asked once: the edit must be visible to the very next request."""
    _settle(http, name, params, fast_ms)
    t = time.perf_counter()
    edit()
    written = time.perf_counter()
    body = http.get(f"/networks/{name}/route", params=params).json()
    lag = (time.perf_counter() - t) * 1e3
    assert seen(body), "edit not seen by the next route"
    return lag, (written - t) * 1e3


def _timed_ms(http: httpx.Client, name: str, params: dict) -> float:
    t = time.perf_counter()
    assert http.get(f"/networks/{name}/route", params=params).status_code == 200
    return (time.perf_counter() - t) * 1e3


def _step_of(body: dict, fid: int) -> dict:
    return next(s for s in body["routes"][0]["legs"][0]["steps"] if fid in s["segment_ids"])


def edit_to_route(http: httpx.Client, conn: psycopg.Connection, url: str, name: str,
                  pair: tuple) -> None:
    """Commit edits that change a route, then time until a route request reflects each: a SQL
    UPDATE of the speed limit, and API PATCHes (speed, lanes, class, one-way, geometry with
    the same end nodes) as the web editor sends them, each timed from the PATCH request."""
    from app.network.tokens import create_token

    with session_scope(url) as session:
        auth = {"Authorization": f"Bearer {create_token(session, 'bench', 'editor')}"}
    (_, ax, ay), (_, bx, by) = pair
    params = {"points": f"{ax!r},{ay!r};{bx!r},{by!r}", "cost": "time"}
    base = http.get(f"/networks/{name}/route", params=params).json()
    driven = base["routes"][0]["legs"][0]["segments"]
    ids = [d["id"] for d in driven]
    fid = ids[len(ids) // 2]
    forward = driven[len(ids) // 2]["forward"]
    item = f"/collections/{name}-segments/items/{fid}"

    tag = {"now": http.get(item).headers["ETag"]}

    def patch(body: dict) -> None:
        r = http.patch(item, json=body, headers={**auth, "If-Match": tag["now"]})
        assert r.status_code == 200, r.text
        tag["now"] = r.headers["ETag"]

    def duration(body: dict) -> float:
        return body["routes"][0]["duration"]

    def sql_speed(kph: int) -> None:
        conn.execute("UPDATE road_segments SET speed_limit_kph = %s WHERE id = %s", (kph, fid))

    conn.execute("UPDATE road_segments SET speed_limit_kph = 50 WHERE id = %s", (fid,))
    fast = min(_timed_ms(http, name, params) for _ in range(3))  # (a known start, untimed)
    lags: dict[str, list[tuple[float, float]]] = {}

    def timed(kind: str, edit, seen=None) -> None:
        """Time one edit; unless told what to look for, the route's duration must change."""
        before = duration(http.get(f"/networks/{name}/route", params=params).json())
        lags.setdefault(kind, []).append(_lag(http, name, params, fast, edit,
                                              seen or (lambda b: duration(b) != before)))

    for kph in (5, 150, 5, 150, 5):
        timed("speed, SQL UPDATE", lambda k=kph: sql_speed(k))
    for kph in (150, 5, 150):
        timed("speed, PATCH", lambda k=kph: patch({"speed_limit_kph": k}))
    lanes_key = "lanes_forward" if forward else "lanes_backward"
    for lanes in (4, 1, 4):
        timed("lanes, PATCH", lambda n=lanes: patch({lanes_key: n}),
              lambda b, n=lanes: _step_of(b, fid)["lanes"] == n)
    for cls in ("primary", "secondary", "primary"):
        timed("class, PATCH", lambda c=cls: patch({"road_class": c}),
              lambda b, c=cls: _step_of(b, fid)["road_class"] == c)
    against = "backward" if forward else "forward"
    for _ in range(2):
        timed("one-way against the trip, PATCH", lambda: patch({"oneway": against}),
              lambda b: fid not in [d["id"] for d in b["routes"][0]["legs"][0]["segments"]])
        patch({"oneway": "none"})
    line = http.get(item).json()["geometry"]["coordinates"]
    (x0, y0), (x1, y1) = line[0], line[-1]
    bulge = {"type": "LineString",
             "coordinates": [line[0], [(x0 + x1) / 2 + 0.01, (y0 + y1) / 2 + 0.01], line[-1]]}
    for _ in range(2):
        timed("geometry (same ends), PATCH", lambda: patch({"geometry": bulge}))
        patch({"geometry": {"type": "LineString", "coordinates": line}})
    every = [x for xs in lags.values() for x, _ in xs]
    print(f"  edit -> next route reflects it (commit or PATCH + HTTP route): median "
          f"{statistics.median(every):.0f} ms, max {max(every):.0f} ms over {len(every)} edits")
    for kind, xs in lags.items():
        total, call = (statistics.median(x[i] for x in xs) for i in (0, 1))
        print(f"    {kind:34s} median {total:6.0f} ms, of which the edit call {call:4.0f} ms "
              f"(n={len(xs)})")


def topology_edits(http: httpx.Client, url: str, name: str, pair: tuple) -> None:
    """Split a segment of a route, then merge it back (each changes the arcs): time from the
    request to the next route, routes meanwhile (Dijkstra while the hierarchy is rebuilt in
    the previous order), and when the hierarchy answers again."""
    from app.network.tokens import create_token

    with session_scope(url) as session:
        auth = {"Authorization": f"Bearer {create_token(session, 'bench-admin', 'admin')}"}
    (_, ax, ay), (_, bx, by) = pair
    params = {"points": f"{ax!r},{ay!r};{bx!r},{by!r}", "cost": "time"}

    def timed() -> tuple[float, dict]:
        t = time.perf_counter()
        body = http.get(f"/networks/{name}/route", params=params).json()
        return (time.perf_counter() - t) * 1e3, body

    fast, base = min(timed() for _ in range(3))[0], timed()[1]
    driven = base["routes"][0]["legs"][0]["segments"]
    ids = [d["id"] for d in driven]
    item = f"/collections/{name}-segments/items/{ids[len(ids) // 2]}"
    halves: list[int] = []
    for kind in ("split", "merge"):
        _settle(http, name, params, fast)
        t0 = time.perf_counter()
        if kind == "split":
            r = http.post(f"{item}/split", json={"fraction": 0.5},
                          headers={**auth, "If-Match": http.get(item).headers["ETag"]})
            halves = [f["id"] for f in r.json()["features"]]
        else:
            tags = ", ".join(http.get(f"/collections/{name}-segments/items/{h}")
                             .headers["ETag"] for h in halves)
            r = http.post(f"/collections/{name}-segments/merge", json={"segments": halves},
                          headers={**auth, "If-Match": tags})
        assert r.status_code == 200, r.text
        body = http.get(f"/networks/{name}/route", params=params).json()
        lag = (time.perf_counter() - t0) * 1e3
        assert abs(body["routes"][0]["duration"] - base["routes"][0]["duration"]) < 1e-3
        during = statistics.median(timed()[0] for _ in range(5))
        while time.perf_counter() - t0 < 600 and timed()[0] > (fast + during) / 2:
            time.sleep(0.5)
        print(f"  {kind} -> next route {lag:.0f} ms; routes meanwhile p50 {during:.0f} ms "
              f"(Dijkstra); hierarchy answers again after {time.perf_counter() - t0:.1f} s "
              f"(route {fast:.0f} ms before the edit)")


def country(args: argparse.Namespace, url: str, conn: psycopg.Connection) -> int:
    """Generate (once, cached in .data/bench) and import the 1M-segment network."""
    from testkit.synthetic_osm import write_country

    pbf = REPO / ".data" / "bench" / f"country-{args.side}.osm.pbf"
    if not pbf.is_file():
        pbf.parent.mkdir(parents=True, exist_ok=True)
        t = time.perf_counter()
        shape = write_country(pbf, args.side)
        print(f"generated {pbf.name}: {shape.nodes} OSM nodes, {shape.ways} ways in "
              f"{time.perf_counter() - t:.0f} s")
    t = time.perf_counter()
    subprocess.run([str(REPO / ".venv" / "bin" / "ugvmap"), "ingest", "network", str(pbf),
                    "--network", "country"], check=True, env={**os.environ, "DATABASE_URL": url})
    took = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    net, segs = conn.execute("SELECT n.id, count(*) FROM networks n JOIN road_segments s ON "
                             "s.network_id = n.id WHERE n.name = 'country' GROUP BY n.id"
                             ).fetchone()
    print(f"import of {segs} segments (ugvmap ingest network, streamed): {took:.0f} s, "
          f"peak RSS {peak:.0f} MiB")
    return net


def main() -> None:
    """Benchmark routing on Andorra and on a large synthetic grid."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=200)
    ap.add_argument("--passes", type=int, default=3)
    ap.add_argument("--grid", type=int, default=224, help="grid side (224 -> 99,904 segments)")
    ap.add_argument("--grid-pairs", type=int, default=60)
    ap.add_argument("--country", action="store_true", help="add the 1M-segment run")
    ap.add_argument("--side", type=int, default=810, help="country side (810 -> 1.02M segments)")
    ap.add_argument("--country-pairs", type=int, default=20)
    args = ap.parse_args()

    with scratch_database("ugvmap_bench") as url, \
            tempfile.TemporaryDirectory(prefix="ugvmap-bench-") as data, \
            psycopg.connect(libpq_dsn(url), autocommit=True) as conn:
        os.environ["DATABASE_URL"] = url
        os.environ["UGVMAP_DATA_DIR"] = data  # hierarchy orders: measured fresh, then reused
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
        country_net = country(args, url, conn) if args.country else None
        build_figures(url, grid_net)
        if country_net is not None:
            build_figures(url, country_net, edits=False)  # timed over HTTP below
        gc.collect()
        env = {"DATABASE_URL": url, "UGVMAP_LOG_LEVEL": "WARNING"}
        with running_server(env, workers=1) as base, \
                httpx.Client(base_url=base, timeout=60) as http:
            print(f"\nHTTP floor (GET /healthz, same server) p50 "
                  f"{http_floor(Wire(base)):.2f} ms")
            if OSM.is_file():
                pairs = compare(http, conn, base, "andorra", osm_net, args.pairs, args.passes)
                table_and_match(http, "andorra", pairs)
            for name, net, n_pairs in (("grid", grid_net, args.grid_pairs),
                                       ("country", country_net, args.country_pairs)):
                if net is None:
                    continue
                edges = pgrouting_edges_sql(net, Cost.TIME)
                pair = node_pairs(conn, net, 1, edges)[0]
                print(f"\n{name}: server hierarchy ready {wait_for_hierarchy(http, name, pair)}")
                compare(http, conn, base, name, net, n_pairs, 1)
                edit_to_route(http, conn, url, name, pair)
                topology_edits(http, url, name, pair)


if __name__ == "__main__":
    main()
