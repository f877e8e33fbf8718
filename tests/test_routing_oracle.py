"""Correctness oracle: route costs equal pgRouting's ``pgr_dijkstra`` on the same edges and costs.

Each route is also checked to be a connected walk of segments in allowed directions. Runs on
a synthetic grid with random speeds and one-way streets, and on the real OSM extract of
Andorra imported with the network importer.
"""

from __future__ import annotations

import itertools
import random

import psycopg
import pytest

from app.db.session import session_scope
from app.routing.costs import Cost, pgrouting_edges_sql
from app.routing.profiles import DEFAULT
from testkit import synthetic
from tests.routing_support import dsn, segment_walk, unique

REL_TOL = 1e-9


def random_pairs(conn: psycopg.Connection, network_id: int, n: int, seed: int) -> list:
    """Nodes on roads the default vehicle drives (a route snaps there, never to a footway)."""
    nodes = conn.execute(
        "SELECT n.id, ST_X(n.geom), ST_Y(n.geom) FROM road_nodes n WHERE n.network_id = %s "
        "AND EXISTS (SELECT 1 FROM road_segments s WHERE (s.source_node = n.id "
        "OR s.target_node = n.id) AND s.road_class <> ALL(%s)) ORDER BY n.id",
        (network_id, sorted(DEFAULT.forbidden))).fetchall()
    rng = random.Random(seed)
    pairs = []
    while len(pairs) < n:
        a, b = rng.sample(nodes, 2)
        pairs.append((a, b))
    return pairs


def assert_connected_walk(body: dict, segs: dict, start: int, end: int) -> None:
    """Segments follow each other end to end, each driven in a direction its one-way allows."""
    node = start
    for leg in body["routes"][0]["legs"]:
        for sid, forward in ((s["id"], s["forward"]) for s in leg["segments"]):
            src, dst, oneway = segs[sid]
            tail, head = (src, dst) if forward else (dst, src)
            assert tail == node, f"segment {sid} does not start where the route is"
            assert oneway == "none" or (oneway == "forward") == forward, "one-way violated"
            node = head
        coords = [s["geometry"]["coordinates"] for s in leg["steps"]]
        for before, after in itertools.pairwise(coords):
            assert before[-1] == after[0], "step geometries do not join"
    assert node == end
    line = body["routes"][0]["geometry"]["coordinates"]
    assert line[0] == body["waypoints"][0]["location"]
    assert line[-1] == body["waypoints"][-1]["location"]


def check_against_pgrouting(client, conn, name: str, network_id: int, cost: Cost,
                            n_pairs: int, seed: int, per_segment_tol: float = 0.0) -> int:
    """Compare ``n_pairs`` random node-to-node routes; returns how many had a path.

    ``per_segment_tol``: allowed excess per driven segment (a hierarchy's weight quantum)."""
    segs = {sid: (s, t, ow) for sid, s, t, ow in conn.execute(
        "SELECT id, source_node, target_node, oneway FROM road_segments WHERE network_id = %s",
        (network_id,))}
    edges = pgrouting_edges_sql(network_id, cost)
    routed = 0
    for (a, ax, ay), (b, bx, by) in random_pairs(conn, network_id, n_pairs, seed):
        row = conn.execute("SELECT max(agg_cost) FROM pgr_dijkstra(%s, %s::bigint, %s::bigint)",
                           (edges, a, b)).fetchone()
        r = client.get(f"/networks/{name}/route",
                       params={"points": f"{ax!r},{ay!r};{bx!r},{by!r}", "cost": cost.value})
        if row[0] is None:
            assert r.status_code == 422 and r.json()["code"] == "NoRoute", (a, b, r.text)
            continue
        assert r.status_code == 200, r.text
        body = r.json()
        ours = body["routes"][0]["weight"]
        tol = REL_TOL * row[0] + per_segment_tol * len(segment_walk(body))
        assert -REL_TOL * row[0] <= ours - row[0] <= tol, (a, b, ours, row[0])
        total = body["routes"][0]["duration" if cost is Cost.TIME else "distance"]
        assert abs(total - ours) <= REL_TOL * row[0]
        assert_connected_walk(body, segs, a, b)
        routed += 1
    return routed


@pytest.fixture(scope="module")
def writer(database_url: str):
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        yield conn


@pytest.fixture(scope="module")
def one_way_grid(writer) -> tuple[str, int]:
    """A 15×15 grid with random speeds; a random quarter of the streets made one-way."""
    name = unique("oracle-grid")
    net = synthetic.grid(writer, name, 15, 15, seed=0.7)
    writer.execute("SELECT setseed(0.3)")
    writer.execute("UPDATE road_segments SET oneway = CASE WHEN random() < 0.5 THEN 'forward' "
                   "ELSE 'backward' END WHERE network_id = %s AND random() < 0.25", (net,))
    return name, net


@pytest.mark.parametrize("cost", list(Cost))
def test_grid_routes_match_pgr_dijkstra(client, writer, one_way_grid, cost) -> None:
    name, net = one_way_grid
    assert check_against_pgrouting(client, writer, name, net, cost, 100, seed=1) > 50


@pytest.fixture(scope="module")
def andorra(shared_data, writer) -> tuple[str, int]:
    from ingest.network import import_network

    name = unique("andorra")
    with session_scope() as session:
        import_network(session, shared_data / "osm" / "andorra.osm.pbf", name)
    net = writer.execute("SELECT id FROM networks WHERE name = %s", (name,)).fetchone()[0]
    return name, net


@pytest.mark.slow
@pytest.mark.parametrize("cost", list(Cost))
def test_osm_routes_match_pgr_dijkstra(client, writer, andorra, cost) -> None:
    name, net = andorra
    routed = check_against_pgrouting(client, writer, name, net, cost, 500, seed=6)
    assert routed > 400  # most pairs lie in the big connected component
