"""Mixed load against ``ugvmap serve --workers 2``, optionally through a database outage.

    .venv/bin/python bench/load.py [--clients 32] [--duration 60] [--workers 2]
                                   [--db-outage SECONDS] [--seed 0]

Creates a throwaway database on the configured PostGIS and a raster store in a temporary
directory, imports ``../shared/data/osm/andorra.osm.pbf`` (a synthetic 40x40 grid without it)
and a synthetic orthophoto layer, starts the server, then runs ``--clients`` asyncio clients
(httpx, one keep-alive connection each) for ``--duration`` seconds, each picking at random:

    raster tile 30 %, MVT tile 25 %, features page 15 %, route 15 %, edit 15 %

after a short warm-up (a few requests of each kind, so each worker has built its routing
graph).
An edit is GET item -> PATCH with ``If-Match`` (an editor token); a 412 re-reads and retries
(up to 5 times). Edits go to 40 "hot" segments so clients really collide. ``--db-outage N``
stops the embedded PostgreSQL a third of the way in and starts it N seconds later: the server
must answer 503 (never another 5xx) meanwhile and recover by itself.

Prints requests, throughput and p50/p99 latency per endpoint, error counts by status, and
checks the edit history: every edit answered 2xx is in ``segment_edits`` exactly once (same
segment, version and value); edits applied whose answer was lost (possible only during the
outage) are counted separately. Exit status 1 if the history check fails or a 5xx other than
503 occurred. The load generator shares the machine with the server, so absolute throughput is
a lower bound of what the server alone does.
"""

from __future__ import annotations

import argparse
import asyncio
import random
import sys
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import morecantile
import psycopg

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from app.db.session import libpq_dsn, session_scope  # noqa: E402
from app.settings import get_settings  # noqa: E402
from cli.ops import embedded  # noqa: E402
from testkit.scratch import bench_database  # noqa: E402
from testkit.server import running_server  # noqa: E402

OSM = REPO.parent / "shared" / "data" / "osm" / "andorra.osm.pbf"
TMS = morecantile.tms.get("WebMercatorQuad")
MIX = {"raster": 30, "mvt": 25, "features": 15, "route": 15, "edit": 15}
HOT_SEGMENTS = 40
MAX_RETRIES = 5
EDITOR = "load-editor"


@dataclass
class Scene:
    """What the clients ask for: tile addresses, node coordinates, hot segments."""

    layer: str
    network: str
    raster_tiles: list[str]
    mvt_tiles: list[str]
    bbox: tuple[float, float, float, float]
    nodes: list[tuple[float, float]]
    hot: list[int]
    token: str


@dataclass
class Stats:
    """Latencies and statuses per endpoint, and every acknowledged edit."""

    latency: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    status: dict[str, Counter] = field(default_factory=lambda: defaultdict(Counter))
    timeline: list[tuple[float, int | str]] = field(default_factory=list)
    """(seconds since start, status or transport error name) of every request."""
    started: float = field(default_factory=time.monotonic)
    edits: list[tuple[int, int, str]] = field(default_factory=list)
    retries: int = 0
    gave_up: int = 0


def percentile(xs: list[float], q: float) -> float:
    """The ``q`` quantile of ``xs`` (nearest rank)."""
    s = sorted(xs)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))] if s else float("nan")


def tiles_over(bounds: tuple[float, float, float, float], zooms: range) -> list[tuple]:
    """Every (z, x, y) meeting lon/lat ``bounds`` at each zoom."""
    return [(t.z, t.x, t.y) for z in zooms for t in TMS.tiles(*bounds, zooms=[z])]


def prepare(url: str, work: Path, seed: int) -> Scene:
    """Load the network, the raster layer and an editor token into the scratch database."""
    from app.network.tokens import create_token
    from ingest.network import import_network
    from ingest.raster.job import ingest_raster
    from testkit.raster_synth import synthetic_utm

    rng = random.Random(seed)
    with session_scope() as session:
        if OSM.exists():
            import_network(session, OSM, "load")
        else:
            from testkit import synthetic

            conn = session.connection().connection.driver_connection
            synthetic.grid(conn, "load", 40, 40)
        token = create_token(session, EDITOR, "editor")
    with psycopg.connect(libpq_dsn(url)) as conn:
        net = conn.execute("SELECT id FROM networks WHERE name = 'load'").fetchone()[0]
        box = conn.execute("SELECT ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e) FROM "
                           "(SELECT ST_Extent(geom) e FROM road_segments WHERE network_id = %s) q",
                           (net,)).fetchone()
        # Route endpoints from the largest strongly connected component: every pair routes.
        nodes = conn.execute(
            "WITH c AS (SELECT component, node FROM pgr_strongComponents('SELECT id, "
            "source_node AS source, target_node AS target, CASE WHEN oneway = ''backward'' "
            "THEN -1 ELSE length_m END AS cost, CASE WHEN oneway = ''forward'' THEN -1 "
            f"ELSE length_m END AS reverse_cost FROM road_segments WHERE network_id = {net}')),"
            " big AS (SELECT component FROM c GROUP BY 1 ORDER BY count(*) DESC LIMIT 1) "
            "SELECT ST_X(n.geom), ST_Y(n.geom) FROM c JOIN big USING (component) "
            "JOIN road_nodes n ON n.id = c.node").fetchall()
        ids = [r[0] for r in conn.execute(
            "SELECT id FROM road_segments WHERE network_id = %s ORDER BY id", (net,))]
    raster, _ = synthetic_utm(work / "ortho.tif", width=2000, height=2000)
    report = ingest_raster([raster], "load-ortho")
    lon0, lat0, lon1, lat1 = report.sources[0].meta["bounds_4326"]
    zoom = report.sources[0].zoom
    raster_tiles = [f"/tiles/load-ortho/{z}/{x}/{y}.png"
                    for z, x, y in tiles_over((lon0, lat0, lon1, lat1), range(zoom - 4,
                                                                             zoom + 1))]
    mid = ((box[0] + box[2]) / 2, (box[1] + box[3]) / 2)
    span = min(box[2] - box[0], box[3] - box[1]) / 4
    core = (mid[0] - span, mid[1] - span, mid[0] + span, mid[1] + span)
    mvt_tiles = [f"/networks/load/tiles/{z}/{x}/{y}.mvt"
                 for z, x, y in tiles_over(core, range(13, 16))]
    return Scene("load-ortho", "load", raster_tiles, mvt_tiles, tuple(box),
                 [tuple(n) for n in nodes], rng.sample(ids, HOT_SEGMENTS), token)


async def one_request(http: httpx.AsyncClient, stats: Stats, kind: str, method: str,
                      url: str, **kwargs) -> httpx.Response | None:
    """Send, time and count one request; a transport failure counts under its exception's
    name (e.g. ``RemoteProtocolError``)."""
    started = time.perf_counter()
    try:
        resp = await http.request(method, url, **kwargs)
    except httpx.HTTPError as exc:
        stats.status[kind][type(exc).__name__] += 1
        stats.timeline.append((time.monotonic() - stats.started, type(exc).__name__))
        await asyncio.sleep(0.05)
        return None
    stats.latency[kind].append(time.perf_counter() - started)
    stats.status[kind][resp.status_code] += 1
    stats.timeline.append((time.monotonic() - stats.started, resp.status_code))
    return resp


async def edit(http: httpx.AsyncClient, stats: Stats, scene: Scene, rng: random.Random,
               client: int, n: int) -> None:
    """Read a hot segment and PATCH its name with If-Match; on 412 read again and retry."""
    fid = rng.choice(scene.hot)
    item = f"/collections/{scene.network}-segments/items/{fid}"
    value = f"load {client}.{n}"
    for attempt in range(MAX_RETRIES):
        got = await one_request(http, stats, "edit-read", "GET", item)
        if got is None or got.status_code != 200:
            return
        resp = await one_request(http, stats, "edit", "PATCH", item, json={"name": value},
                                 headers={"Authorization": f"Bearer {scene.token}",
                                          "If-Match": got.headers["etag"]})
        if resp is None:
            return
        if resp.status_code == 200:
            stats.edits.append((fid, int(resp.headers["etag"].strip('"')), value))
            return
        if resp.status_code != 412:
            return
        stats.retries += attempt == 0
    stats.gave_up += 1


async def client_loop(base: str, scene: Scene, stats: Stats, deadline: float,
                      client: int, seed: int) -> None:
    """One client: random operations from :data:`MIX` until the deadline."""
    rng = random.Random(seed * 1000 + client)
    kinds, weights = list(MIX), list(MIX.values())
    async with httpx.AsyncClient(base_url=base, timeout=30.0) as http:
        n = 0
        while time.monotonic() < deadline:
            n += 1
            kind = rng.choices(kinds, weights)[0]
            if kind == "raster":
                await one_request(http, stats, kind, "GET", rng.choice(scene.raster_tiles))
            elif kind == "mvt":
                await one_request(http, stats, kind, "GET", rng.choice(scene.mvt_tiles))
            elif kind == "features":
                x0, y0, x1, y1 = scene.bbox
                w, h = (x1 - x0) / 20, (y1 - y0) / 20
                x, y = rng.uniform(x0, x1 - w), rng.uniform(y0, y1 - h)
                await one_request(http, stats, kind, "GET",
                                  f"/collections/{scene.network}-segments/items",
                                  params={"bbox": f"{x},{y},{x + w},{y + h}", "limit": 50})
            elif kind == "route":
                a, b = rng.sample(scene.nodes, 2)
                await one_request(http, stats, kind, "GET", f"/networks/{scene.network}/route",
                                  params={"points": f"{a[0]!r},{a[1]!r};{b[0]!r},{b[1]!r}"})
            else:
                await edit(http, stats, scene, rng, client, n)


async def outage(seconds: float, after: float, stats: Stats, log: list[str]) -> None:
    """Stop the embedded cluster ``after`` seconds in, start it ``seconds`` later."""
    cluster = embedded.cluster_from(get_settings())
    await asyncio.sleep(after)
    await asyncio.to_thread(embedded.stop, cluster)
    log.append(f"t={time.monotonic() - stats.started:.1f}s database stopped")
    await asyncio.sleep(seconds)
    await asyncio.to_thread(embedded.start, cluster)
    back = time.monotonic() - stats.started
    log.append(f"t={back:.1f}s database started again")
    stats.timeline.append((back, "restarted"))


async def run_load(base: str, scene: Scene, args: argparse.Namespace) -> tuple[Stats, float,
                                                                               list[str]]:
    """All clients (and the outage, if asked) at once; returns the stats and elapsed time."""
    stats = Stats()
    log: list[str] = []
    deadline = stats.started + args.duration
    tasks = [client_loop(base, scene, stats, deadline, c, args.seed)
             for c in range(args.clients)]
    if args.db_outage:
        tasks.append(outage(args.db_outage, args.duration / 3, stats, log))
    await asyncio.gather(*tasks)
    return stats, time.monotonic() - stats.started, log


def recovery(stats: Stats) -> str:
    """After the restart: how long until the first 2xx, and errors answered after that."""
    back = next(t for t, s in stats.timeline if s == "restarted")
    after = [(t, s) for t, s in stats.timeline if t > back and s != "restarted"]
    first_ok = next((t for t, s in after if isinstance(s, int) and s < 300), None)
    if first_ok is None:
        return "no 2xx after the database came back: the service did not recover"
    late = Counter(s for t, s in after if t > first_ok and not (isinstance(s, int)
                                                                 and s < 500))
    return (f"first 2xx {first_ok - back:.2f} s after the restart; afterwards: "
            + (", ".join(f"{s}: {n}" for s, n in late.items()) or "no 5xx or transport "
               "errors"))


def warm_up(base: str, scene: Scene, rounds: int = 8) -> None:
    """A few requests of each kind on fresh connections (so both workers get some): the
    first route builds the worker's graph, which is not what the load measures."""
    for i in range(rounds):
        a, b = scene.nodes[i], scene.nodes[-1 - i]
        for url in (f"/networks/{scene.network}/route?points={a[0]!r},{a[1]!r};"
                    f"{b[0]!r},{b[1]!r}", scene.raster_tiles[i], scene.mvt_tiles[i]):
            httpx.get(base + url, timeout=60.0)


def check_history(url: str, stats: Stats) -> tuple[int, int, int]:
    """(acknowledged edits missing from history, present more than once, applied but not
    acknowledged)."""
    with psycopg.connect(libpq_dsn(url)) as conn:
        rows = conn.execute("SELECT segment_id, version_to, new->>'name' FROM segment_edits "
                            "WHERE edited_by = %s AND action = 'update'", (EDITOR,)).fetchall()
    history = Counter((r[0], r[1], r[2]) for r in rows)
    acked = Counter(stats.edits)
    missing = sum(1 for e in acked if history[e] == 0)
    doubled = sum(1 for e in acked if history[e] > 1) + sum(1 for n in acked.values() if n > 1)
    unacked = sum(1 for e in history if e not in acked)
    return missing, doubled, unacked


def report(stats: Stats, elapsed: float, log: list[str], history: tuple[int, int, int],
           args: argparse.Namespace) -> bool:
    """Print the tables; True when the run passed its checks."""
    total = sum(sum(c.values()) for c in stats.status.values())
    print(f"\n{args.clients} clients, {elapsed:.1f} s, {args.workers} workers: "
          f"{total} requests, {total / elapsed:.0f} req/s")
    for line in log:
        print("  " + line)
    if args.db_outage:
        print("  " + recovery(stats))
    print(f"\n{'endpoint':<11}{'requests':>9}{'req/s':>8}{'p50 ms':>9}{'p99 ms':>9}  statuses")
    for kind in ("raster", "mvt", "features", "route", "edit-read", "edit"):
        lat = stats.latency.get(kind, [])
        count = sum(stats.status[kind].values())
        statuses = ", ".join(f"{s}: {n}" for s, n in sorted(stats.status[kind].items(),
                                                             key=lambda i: str(i[0])))
        print(f"{kind:<11}{count:>9}{count / elapsed:>8.1f}{1000 * percentile(lat, 0.5):>9.1f}"
              f"{1000 * percentile(lat, 0.99):>9.1f}  {statuses}")
    errors: Counter = Counter()
    for counter in stats.status.values():
        errors.update({s: n for s, n in counter.items() if isinstance(s, str) or s >= 400})
    print("\nerrors by status: " + (", ".join(
        f"{s}: {n}" for s, n in sorted(errors.items(), key=lambda i: str(i[0]))) or "none"))
    bad_5xx = sum(n for s, n in errors.items() if isinstance(s, int) and s >= 500 and s != 503)
    transport = sum(n for s, n in errors.items() if isinstance(s, str))
    missing, doubled, unacked = history
    print(f"edits: {len(stats.edits)} acknowledged (2xx), {stats.retries} needed a 412 retry, "
          f"{stats.gave_up} gave up after {MAX_RETRIES} conflicts")
    print(f"history check: {missing} acknowledged edits missing, {doubled} duplicated, "
          f"{unacked} applied but not acknowledged (answer lost)")
    ok = missing == 0 and doubled == 0 and bad_5xx == 0
    print(f"5xx other than 503: {bad_5xx}; transport errors: {transport}")
    print(f"RESULT: {'PASS' if ok else 'FAIL'}")
    return ok


def main() -> int:
    """Set up, serve, load, check, report."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--clients", type=int, default=32)
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--db-outage", type=float, default=0.0, metavar="SECONDS")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.db_outage and not get_settings().embedded:
        parser.error("--db-outage stops the embedded cluster; unset DATABASE_URL")
    with bench_database("ugvmap_load") as (url, tmp, env):
        t = time.perf_counter()
        scene = prepare(url, tmp, args.seed)
        print(f"prepared in {time.perf_counter() - t:.1f} s: {len(scene.raster_tiles)} raster "
              f"tiles, {len(scene.mvt_tiles)} MVT tiles, {len(scene.nodes)} routable nodes")
        with running_server(env, workers=args.workers, timeout_s=120) as base:
            warm_up(base, scene)
            stats, elapsed, log = asyncio.run(run_load(base, scene, args))
        history = check_history(url, stats)
        ok = report(stats, elapsed, log, history, args)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
