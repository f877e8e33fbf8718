"""A randomized storm of network edits against ``ugvmap serve``, then the network checked.

    .venv/bin/python bench/write_storm.py [--minutes 15] [--clients 8] [--workers 2]
                                          [--baseline-seconds 20] [--seed 0]

Creates a throwaway database on the configured PostGIS, imports
``../shared/data/osm/andorra.osm.pbf`` (a synthetic 40x40 grid without it), starts the server
and loads its routing graph, then runs ``--clients`` asyncio clients for ``--minutes``, each
picking at random one of the writes the editing API has, on features it reads first:

    PATCH a segment's attributes 20 %, PATCH its line (a vertex added) 10 %, PUT it whole 10 %,
    POST a segment 12 %, DELETE a segment 8 %, split 10 %, merge (POST merge or DELETE of a
    node between two segments) 10 %, move a node (PATCH/PUT its Point) 12 %, POST a node 8 %

half of them with ``If-Match`` (the ETag just read), half without; every new coordinate is
computed in floating point (offsets, interpolations, angles), so they are arbitrary doubles,
not short decimals. A 412, 404 or 422 is a lost race or a refused edit, which is fine; a 5xx
is not.

The baseline, measured in the same run before the storm: one client alone for
``--baseline-seconds``; the table prints each write's p50 / p99 in the storm and its p50
as a ratio of the baseline's.

Then the checks, each PASS or FAIL (exit status 1 if any fails):

- ``ugvmap network validate`` finds the network clean;
- every accepted write (2xx) is in the history (its feature, action and resulting version;
  for a write without If-Match that changed nothing, the version it answered, by any action);
- every history of a feature ever edited reads back (200, JSON);
- 0 answers 5xx (409 ``Conflict`` is allowed but counted);
- routes between random nodes of the edited network's largest strongly connected piece from
  the server whose graph followed every edit live equal those of a second server that loads
  the network fresh (same code, same distance and duration to 1e-9).
"""

from __future__ import annotations

import argparse
import asyncio
import math
import os
import random
import subprocess
import sys
import time
from collections import Counter, defaultdict
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import psycopg

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from app.db.session import libpq_dsn, session_scope  # noqa: E402
from app.routing.costs import Cost, pgrouting_edges_sql  # noqa: E402
from testkit.network_helpers import node_pairs  # noqa: E402
from testkit.scratch import bench_database  # noqa: E402
from testkit.server import running_server  # noqa: E402

OSM = REPO.parent / "shared" / "data" / "osm" / "andorra.osm.pbf"
NETWORK = "storm"
ROUTE_PAIRS = 300
ANY_ACTION = "*"
"""An accepted write whose version any history row may hold (:meth:`Client.accept_edit`)."""
# Metres as degrees of latitude (and of longitude at Andorra's ~42.5 N, near enough for
# choosing random offsets).
M_LAT = 1 / 111_320
M_LON = 1 / (111_320 * math.cos(math.radians(42.5)))


@dataclass
class Scene:
    """The network's collections, tokens and the ids clients pick from (stale ids are fine:
    they make 404s, as a real client with an old page would)."""

    segments: str
    nodes: str
    editor: dict[str, str]
    admin: dict[str, str]
    segment_ids: list[int]
    node_ids: list[int]


@dataclass
class Stats:
    """Latencies and statuses per write kind, and every accepted write."""

    latency: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    status: dict[str, Counter] = field(default_factory=lambda: defaultdict(Counter))
    accepted: list[tuple[str, int, frozenset[str], int | None]] = field(default_factory=list)
    """(history table, feature id, the actions it may be recorded as, version_to or None)."""
    unchanged: int = 0
    """Writes answered 200 that changed nothing (a value set to what it was): no version,
    no history row, as the API documents."""


class Client:
    """One client: an HTTP connection, a random source, the shared scene and stats."""

    def __init__(self, http: httpx.AsyncClient, scene: Scene, stats: Stats,
                 rng: random.Random) -> None:
        self.http, self.scene, self.stats, self.rng = http, scene, stats, rng

    async def send(self, kind: str, method: str, url: str, **kw: Any) -> httpx.Response:
        """Send one request, counting its status under ``kind`` (and timing it if a write)."""
        started = time.perf_counter()
        r = await self.http.request(method, url, **kw)
        if method != "GET":
            self.stats.latency[kind].append(time.perf_counter() - started)
        self.stats.status[kind][r.status_code] += 1
        return r

    def accept(self, table: str, fid: int, actions: str, version: int | None) -> None:
        """Note a write the server accepted, to be found in the history afterwards."""
        self.stats.accepted.append((table, fid, frozenset(actions.split()), version))

    def accept_edit(self, table: str, fid: int, actions: str, read: httpx.Response,
                    written: httpx.Response) -> None:
        """Note an accepted edit of a feature read first; one that left the version as read
        changed nothing and has no history row. An edit without If-Match that changed
        nothing answers the version current when it ran, which another client's write may
        have made meanwhile (a PUT, a split): its version must be in the history, by
        whichever action (a 15-minute storm had one such PATCH of ``surface`` to the value a
        concurrent write had just given it, counted missing as an "update")."""
        if version(written) == version(read):
            self.stats.unchanged += 1
        elif "if-match" not in written.request.headers:
            self.accept(table, fid, ANY_ACTION, version(written))
        else:
            self.accept(table, fid, actions, version(written))

    def condition(self, read: httpx.Response, token: dict[str, str]) -> dict[str, str]:
        """The token, and half the time the ETag just read as If-Match."""
        return {**token, "If-Match": read.headers["etag"]} if self.rng.random() < 0.5 \
            else dict(token)

    async def write(self, kind: str) -> None:
        """One write of ``kind``, on a random feature read first (none if it is gone)."""
        _, reads, write = MIX[kind]
        collection, ids = ((self.scene.segments, self.scene.segment_ids) if reads == "segment"
                           else (self.scene.nodes, self.scene.node_ids))
        fid = self.rng.choice(ids)
        read = await self.send(kind, "GET", f"{collection}/{fid}")
        if read.status_code == 200:
            await write(self, fid, read)

    def offset(self, position: list[float], metres: float) -> list[float]:
        """``position`` moved ``metres`` in a random direction, computed in floating point."""
        angle = self.rng.uniform(0, 2 * math.pi)
        return [position[0] + metres * math.cos(angle) * M_LON,
                position[1] + metres * math.sin(angle) * M_LAT]

    def along(self, coords: list[list[float]]) -> list[float]:
        """A point interpolated at a random fraction of a random piece of a line."""
        i = self.rng.randrange(len(coords) - 1)
        t = self.rng.uniform(0.2, 0.8)
        (x0, y0), (x1, y1) = coords[i], coords[i + 1]
        return [x0 + t * (x1 - x0), y0 + t * (y1 - y0)]

    # -- the writes ------------------------------------------------------------------------
    async def patch_attributes(self, fid: int, read: httpx.Response) -> None:
        """PATCH one attribute of a segment (name, speed, attrs or surface)."""
        patch = self.rng.choice([
            {"name": f"storm {self.rng.random()}"},
            {"speed_limit_kph": round(self.rng.uniform(10, 120), 3)},
            {"attrs": {"storm": self.rng.random(), "note": {"depth": [1, 2]}}},
            {"surface": self.rng.choice(["asphalt", "gravel", None])},
        ])
        r = await self.send("patch-attrs", "PATCH", f"{self.scene.segments}/{fid}", json=patch,
                            headers=self.condition(read, self.scene.editor))
        if r.status_code == 200:
            self.accept_edit("segment_edits", fid, "update", read, r)

    async def patch_line(self, fid: int, read: httpx.Response) -> None:
        """PATCH a segment's line with a vertex added off the middle of one of its pieces."""
        coords = read.json()["geometry"]["coordinates"]
        i = self.rng.randrange(len(coords) - 1)
        mid = self.offset([(coords[i][0] + coords[i + 1][0]) / 2,
                           (coords[i][1] + coords[i + 1][1]) / 2], self.rng.uniform(0, 0.5))
        line = [*coords[:i + 1], mid, *coords[i + 1:]]
        r = await self.send("patch-line", "PATCH", f"{self.scene.segments}/{fid}",
                            json={"geometry": {"type": "LineString", "coordinates": line}},
                            headers=self.condition(read, self.scene.editor))
        if r.status_code == 200:
            self.accept_edit("segment_edits", fid, "update", read, r)

    async def put_segment(self, fid: int, read: httpx.Response) -> None:
        """PUT a segment back whole, as QGIS does, with its name and lanes changed."""
        feature = read.json()
        feature["properties"]["name"] = f"put {self.rng.random()}"
        feature["properties"]["lanes_forward"] = self.rng.randint(1, 3)
        r = await self.send("put-segment", "PUT", f"{self.scene.segments}/{fid}", json=feature,
                            headers={**self.condition(read, self.scene.editor),
                                     "Content-Type": "application/geo+json"})
        if r.status_code == 200:
            self.accept_edit("segment_edits", fid, "replace", read, r)

    async def post_segment(self, fid: int, read: httpx.Response) -> None:
        """POST a road from a node to a point 15-80 m away in a random direction."""
        start = read.json()["geometry"]["coordinates"]
        end = self.offset(start, self.rng.uniform(15, 80))
        line = [start, self.offset([(start[0] + end[0]) / 2, (start[1] + end[1]) / 2], 3),
                end]
        r = await self.send("post-segment", "POST", self.scene.segments, headers={
            **self.scene.editor, "Content-Type": "application/geo+json"}, json={
            "type": "Feature", "properties": {"name": "storm road"},
            "geometry": {"type": "LineString", "coordinates": line}})
        if r.status_code == 201:
            created = r.json()
            self.scene.segment_ids.append(created["id"])
            self.scene.node_ids.extend((created["properties"]["source_node"],
                                        created["properties"]["target_node"]))
            self.accept("segment_edits", created["id"], "create", 1)

    async def delete_segment(self, fid: int, read: httpx.Response) -> None:
        """DELETE a segment."""
        r = await self.send("delete-segment", "DELETE", f"{self.scene.segments}/{fid}",
                            headers=self.condition(read, self.scene.editor))
        if r.status_code == 204:
            self.accept("segment_edits", fid, "delete", None)

    async def split(self, fid: int, read: httpx.Response) -> None:
        """Split a segment at a random fraction or at a point interpolated along it."""
        body = {"fraction": self.rng.uniform(0.1, 0.9)} if self.rng.random() < 0.5 else \
            {"point": self.along(read.json()["geometry"]["coordinates"])}
        r = await self.send("split", "POST", f"{self.scene.segments}/{fid}/split", json=body,
                            headers=self.condition(read, self.scene.admin))
        if r.status_code == 200:
            kept, new = r.json()["features"]
            self.accept("segment_edits", kept["id"], "split", kept["properties"]["version"])
            self.accept("segment_edits", new["id"], "split", 1)
            self.scene.segment_ids.append(new["id"])
            self.scene.node_ids.append(kept["properties"]["target_node"])

    async def merge(self, fid: int, read: httpx.Response) -> None:
        """Merge the two segments at one end of a segment, when that node joins just two:
        by POST merge or by DELETE of the node."""
        node = read.json()["properties"][self.rng.choice(["source_node", "target_node"])]
        at = [(await self.send("merge", "GET", self.scene.segments,
                               params={end: node})).json()["features"]
              for end in ("source_node", "target_node")]
        pair = [f["id"] for f in at[0] + at[1]]
        if len(pair) != 2 or pair[0] == pair[1]:
            return
        if self.rng.random() < 0.5:
            r = await self.send("merge", "DELETE", f"{self.scene.nodes}/{node}",
                                headers=self.scene.admin)
            if r.status_code == 204:
                self.accept("node_edits", node, "delete", None)
                for sid in pair:  # which one was kept is the server's choice (the lower id)
                    self.accept("segment_edits", sid, "merge", None)
            return
        r = await self.send("merge", "POST", self.scene.segments.removesuffix("/items")
                            + "/merge", json={"segments": pair}, headers=self.scene.admin)
        if r.status_code == 200:
            self.accept("segment_edits", pair[0], "merge", version(r))
            self.accept("segment_edits", pair[1], "merge", None)

    async def move_node(self, fid: int, read: httpx.Response) -> None:
        """Move a node 1 cm to 2 m (PATCH or PUT of its Point)."""
        node = read.json()
        point = {"type": "Point",
                 "coordinates": self.offset(node["geometry"]["coordinates"],
                                            self.rng.uniform(0.01, 2.0))}
        headers = self.condition(read, self.scene.editor)
        if self.rng.random() < 0.5:
            r = await self.send("move-node", "PATCH", f"{self.scene.nodes}/{fid}",
                                json={"geometry": point}, headers=headers)
        else:
            r = await self.send("move-node", "PUT", f"{self.scene.nodes}/{fid}", json={
                "type": "Feature", "geometry": point,
                "properties": {"traffic_light": self.rng.random() < 0.3}},
                headers={**headers, "Content-Type": "application/geo+json"})
        if r.status_code == 200:
            self.accept_edit("node_edits", fid, "move update replace", read, r)

    async def post_node(self, fid: int, read: httpx.Response) -> None:
        """POST a node at a point interpolated along a segment (which it splits)."""
        point = self.along(read.json()["geometry"]["coordinates"])
        r = await self.send("post-node", "POST", self.scene.nodes, headers={
            **self.scene.admin, "Content-Type": "application/geo+json"}, json={
            "type": "Feature", "properties": {},
            "geometry": {"type": "Point", "coordinates": point}})
        if r.status_code == 201:
            self.scene.node_ids.append(r.json()["id"])
            self.accept("node_edits", r.json()["id"], "create", 1)


def version(r: httpx.Response) -> int:
    """The version an answer's ETag names."""
    return int(r.headers["etag"].strip('"').removeprefix("W/").strip('"'))


Write = Callable[[Client, int, httpx.Response], Awaitable[None]]
MIX: dict[str, tuple[int, str, Write]] = {  # weight, what it reads first, the write
    "patch-attrs": (20, "segment", Client.patch_attributes),
    "patch-line": (10, "segment", Client.patch_line),
    "put-segment": (10, "segment", Client.put_segment),
    "post-segment": (12, "node", Client.post_segment),
    "delete-segment": (8, "segment", Client.delete_segment),
    "split": (10, "segment", Client.split),
    "merge": (10, "segment", Client.merge),
    "move-node": (12, "node", Client.move_node),
    "post-node": (8, "segment", Client.post_node),
}


async def storm(base: str, scene: Scene, clients: int, seconds: float, seed: int) -> Stats:
    """``clients`` clients writing at random until ``seconds`` have passed."""
    stats = Stats()
    deadline = time.monotonic() + seconds
    kinds = list(MIX)
    weights = [MIX[k][0] for k in kinds]

    async def one(n: int) -> None:
        rng = random.Random(seed * 1000 + n)
        async with httpx.AsyncClient(base_url=base, timeout=60.0) as http:
            client = Client(http, scene, stats, rng)
            while time.monotonic() < deadline:
                await client.write(rng.choices(kinds, weights)[0])

    await asyncio.gather(*(one(n) for n in range(clients)))
    return stats


def prepare(url: str) -> Scene:
    """Import the network and make the tokens; the ids clients start from."""
    from app.network.tokens import create_token
    from ingest.network import import_network

    with session_scope() as session:
        if OSM.exists():
            import_network(session, OSM, NETWORK)
        else:
            from testkit import synthetic

            synthetic.grid(session.connection().connection.driver_connection, NETWORK, 40, 40)
        editor = create_token(session, "storm-editor", "editor")
        admin = create_token(session, "storm-admin", "admin")
    with psycopg.connect(libpq_dsn(url)) as conn:
        segments = [r[0] for r in conn.execute(
            "SELECT s.id FROM road_segments s JOIN networks n ON n.id = s.network_id "
            "WHERE n.name = %s", (NETWORK,))]
        nodes = [r[0] for r in conn.execute(
            "SELECT d.id FROM road_nodes d JOIN networks n ON n.id = d.network_id "
            "WHERE n.name = %s", (NETWORK,))]
    return Scene(f"/collections/{NETWORK}-segments/items", f"/collections/{NETWORK}-nodes/items",
                 {"Authorization": f"Bearer {editor}"}, {"Authorization": f"Bearer {admin}"},
                 segments, nodes)


def route_pairs(url: str, seed: int) -> list[str]:
    """``points`` values of :data:`ROUTE_PAIRS` random pairs of nodes of the network as it
    is now, inside its largest strongly connected piece (pairs that have a route: the
    storm's deletions cut a mountain network into many pieces)."""
    with psycopg.connect(libpq_dsn(url)) as conn:
        net = conn.execute("SELECT id FROM networks WHERE name = %s", (NETWORK,)).fetchone()
        assert net is not None
        pairs = node_pairs(conn, net[0], ROUTE_PAIRS, pgrouting_edges_sql(net[0], Cost.TIME),
                           seed)
    return [f"{a[1]!r},{a[2]!r};{b[1]!r},{b[2]!r}" for a, b in pairs]


def routes(base: str, pairs: list[str]) -> list[tuple[str, float, float]]:
    """(code, distance, duration) of the route between each pair."""
    out = []
    with httpx.Client(base_url=base, timeout=120.0) as http:
        for points in pairs:
            body = http.get(f"/networks/{NETWORK}/route", params={"points": points}).json()
            best = body.get("routes", [{}])[0]
            out.append((body["code"], best.get("distance", 0.0), best.get("duration", 0.0)))
    return out


def check_history(url: str, stats: Stats) -> tuple[int, int]:
    """(accepted writes, of them missing from the history)."""
    with psycopg.connect(libpq_dsn(url)) as conn:
        rows = {(table, r[0], r[1], r[2]) for table, column in (("segment_edits", "segment_id"),
                                                                ("node_edits", "node_id"))
                for r in conn.execute(f"SELECT {column}, action, version_to FROM {table}")}
    by_feature: dict[tuple[str, int], list[tuple[str, int | None]]] = defaultdict(list)
    for table, fid, action, version_to in rows:
        by_feature[table, fid].append((action, version_to))
    missing = [(table, fid, sorted(actions), v) for table, fid, actions, v in stats.accepted
               if not any((a in actions or ANY_ACTION in actions) and (v is None or vt == v)
                          for a, vt in by_feature[table, fid])]
    for write in missing[:10]:
        print("accepted, not in the history:", write)
    return len(stats.accepted), len(missing)


async def read_histories(base: str, url: str) -> tuple[int, Counter]:
    """GET the history of every feature ever edited; (how many, their statuses)."""
    with psycopg.connect(libpq_dsn(url)) as conn:
        edited = [(f"/collections/{NETWORK}-{kind}/items/{r[0]}/history")
                  for kind, table, column in (("segments", "segment_edits", "segment_id"),
                                              ("nodes", "node_edits", "node_id"))
                  for r in conn.execute(f"SELECT DISTINCT {column} FROM {table}")]
    statuses: Counter = Counter()
    queue = list(edited)

    async def reader() -> None:
        async with httpx.AsyncClient(base_url=base, timeout=60.0) as http:
            while queue:
                r = await http.get(queue.pop())
                ok = r.status_code == 200 and isinstance(r.json().get("edits"), list)
                statuses[r.status_code if ok or r.status_code != 200 else "bad JSON"] += 1

    await asyncio.gather(*(reader() for _ in range(8)))
    return len(edited), statuses


def validate(url: str) -> tuple[bool, str]:
    """``ugvmap network validate``: (clean, its report)."""
    run = subprocess.run([sys.executable, "-m", "cli", "network", "validate", NETWORK],
                         cwd=REPO, env={**os.environ, "DATABASE_URL": url},
                         capture_output=True, text=True)
    return run.returncode == 0, (run.stdout + run.stderr).strip()


def percentile(xs: list[float], q: float) -> float:
    """The ``q`` quantile of ``xs`` (nearest rank)."""
    s = sorted(xs)
    return s[min(len(s) - 1, round(q * (len(s) - 1)))] if s else float("nan")


def table(stats: Stats, baseline: Stats, seconds: float) -> None:
    """Print each write's count, rate, latencies and statuses."""
    print(f"\n{'write':<15}{'sent':>7}{'/s':>7}{'p50 ms':>8}{'p99 ms':>8}{'p50/base':>9}"
          "  statuses (reads included)")
    for kind in MIX:
        lat, base = stats.latency.get(kind, []), baseline.latency.get(kind, [])
        ratio = percentile(lat, 0.5) / percentile(base, 0.5) if lat and base else float("nan")
        statuses = ", ".join(f"{s}: {n}" for s, n in sorted(stats.status[kind].items()))
        print(f"{kind:<15}{len(lat):>7}{len(lat) / seconds:>7.1f}"
              f"{1000 * percentile(lat, 0.5):>8.1f}{1000 * percentile(lat, 0.99):>8.1f}"
              f"{ratio:>9.2f}  {statuses}")


def main() -> int:
    """Set up, baseline, storm, check, report."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--clients", type=int, default=8)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--baseline-seconds", type=float, default=20.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with bench_database("ugvmap_storm") as (url, _, env):
        t = time.perf_counter()
        scene = prepare(url)
        print(f"prepared in {time.perf_counter() - t:.1f} s: {len(scene.segment_ids)} "
              f"segments, {len(scene.node_ids)} nodes")
        with running_server(env, workers=args.workers, timeout_s=120) as base:
            warm = route_pairs(url, args.seed)[:1]
            for _ in range(2 * args.workers):  # every worker loads its graph: edits patch it
                routes(base, warm)
            baseline = asyncio.run(storm(base, scene, 1, args.baseline_seconds, args.seed + 1))
            seconds = 60 * args.minutes
            stats = asyncio.run(storm(base, scene, args.clients, seconds, args.seed))
            pairs = route_pairs(url, args.seed)
            live = routes(base, pairs)
            read, statuses = asyncio.run(read_histories(base, url))
        with running_server(env, workers=1, timeout_s=120) as fresh_base:
            fresh = routes(fresh_base, pairs)
        clean, report = validate(url)
        accepted, missing = check_history(url, Stats(accepted=baseline.accepted
                                                     + stats.accepted))
    print(f"\n{args.clients} clients, {args.minutes:g} min, {args.workers} workers; "
          f"baseline: 1 client, {args.baseline_seconds:g} s, same mix")
    table(stats, baseline, seconds)
    rates = [sum(map(len, s.latency.values())) / t
             for s, t in ((stats, seconds), (baseline, args.baseline_seconds))]
    print(f"writes/s: {rates[0]:.1f} with {args.clients} clients, {rates[1]:.1f} with 1 "
          f"(baseline); ratio {rates[0] / rates[1]:.2f} (a network's edits run one at a time)")
    fivexx = sum(n for kind in (baseline, stats) for c in kind.status.values()
                 for s, n in c.items() if s >= 500)
    conflicts = sum(c[409] for kind in (baseline, stats) for c in kind.status.values())
    same = sum(1 for a, b in zip(live, fresh, strict=True)
               if a[0] == b[0] and math.isclose(a[1], b[1], rel_tol=1e-9)
               and math.isclose(a[2], b[2], rel_tol=1e-9))
    found = sum(1 for code, _, _ in live if code == "Ok")
    checks = {
        "network validate clean": (clean, report.splitlines()[-1] if report else ""),
        "every accepted write in the history": (missing == 0,
                                                f"{accepted} accepted, {missing} missing; "
                                                f"{stats.unchanged + baseline.unchanged} "
                                                "changed nothing (200, no new version)"),
        "every history readable": (set(statuses) <= {200},
                                   f"{read} histories: " + ", ".join(
                                       f"{s}: {n}" for s, n in statuses.items())),
        "0 x 5xx": (fivexx == 0, f"{fivexx} x 5xx, {conflicts} x 409 Conflict"),
        "routes equal a fresh load": (same == len(pairs),
                                      f"{same} of {len(pairs)} equal ({found} found a route)"),
    }
    print()
    for name, (ok, detail) in checks.items():
        print(f"{'PASS' if ok else 'FAIL'}  {name}: {detail}")
    if not clean:
        print(report)
    ok = all(ok for ok, _ in checks.values())
    print(f"RESULT: {'PASS' if ok else 'FAIL'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
