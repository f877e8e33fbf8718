"""Routes through the contraction hierarchy equal ``pgr_dijkstra``, before and after live edits.

Networks here are above ``hierarchy_min_segments`` (1000), so once the hierarchy is built the
route endpoint answers through it; each test waits for that and checks the hierarchy did
answer (its ``answered`` counter), so a silent fallback to Dijkstra would fail them.
"""

from __future__ import annotations

import random
import time
from dataclasses import replace

import numpy as np
import psycopg
import pytest

from app.db.session import session_scope
from app.routing.costs import Cost
from app.routing.graph import CostGraph, RoadGraph, Shape
from app.routing.hierarchy import Hierarchy, quantise
from app.routing.live import GraphRegistry, read_segments, registry
from app.routing.settings import routing_settings
from app.settings import get_settings
from testkit import synthetic
from testkit.network_helpers import bearer
from testkit.synthetic_osm import write_country
from tests.routing_support import dsn, route, segment_walk, unique
from tests.test_routing_live import assert_same_graph
from tests.test_routing_oracle import check_against_pgrouting


@pytest.fixture(scope="module")
def writer(database_url: str):
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        yield conn


def cost_graph(net: int, cost: Cost) -> CostGraph:
    graph = registry(get_settings().database_url)._graphs[net]
    return graph.costs(cost)


def hierarchy_ready(client, name: str, net: int, cost: Cost, timeout_s: float = 60) -> Hierarchy:
    """Load the graph (one route request), then wait until the hierarchy can answer."""
    lon, lat = _any_node(net)
    client.get(f"/networks/{name}/route", params={"points": f"{lon},{lat};{lon},{lat}"})
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        cg = cost_graph(net, cost)
        assert cg.hierarchy is not None, "network too small for a hierarchy"
        if cg.hierarchy.metric(cg.hierarchy_key, cg.version, cg.arc_costs, cg.max_rate):
            return cg.hierarchy
        time.sleep(0.05)
    raise AssertionError("the hierarchy was not built in time")


def _any_node(net: int) -> tuple[float, float]:
    with psycopg.connect(dsn(get_settings().database_url)) as conn:
        return conn.execute("SELECT ST_X(geom), ST_Y(geom) FROM road_nodes WHERE network_id = %s "
                            "ORDER BY id LIMIT 1", (net,)).fetchone()


def oracle(client, writer, name: str, net: int, cost: Cost, pairs: int, seed: int) -> int:
    """Compare with pgr_dijkstra; every route must come from the hierarchy."""
    hierarchy = hierarchy_ready(client, name, net, cost)
    before = hierarchy.answered
    cg = cost_graph(net, cost)
    quantum = hierarchy.metric(cg.hierarchy_key, cg.version, cg.arc_costs, cg.max_rate).quantum
    routed = check_against_pgrouting(client, writer, name, net, cost, pairs, seed,
                                     per_segment_tol=quantum)
    assert hierarchy.answered - before >= routed
    return routed


@pytest.fixture(scope="module")
def country(writer, tmp_path_factory) -> tuple[str, int]:
    """The synthetic country network (class hierarchy, one-way streets, deletions), small,
    through the real OSM importer."""
    pbf = tmp_path_factory.mktemp("country") / "country.osm.pbf"
    write_country(pbf, 36, seed=3)
    name = unique("country")
    from ingest.network import import_network

    with session_scope() as session:
        summary = import_network(session, pbf, name)
    assert summary.segments > 1500
    return name, summary.network_id


@pytest.mark.parametrize("cost", list(Cost))
def test_country_routes_match_pgr_dijkstra(client, writer, country, cost) -> None:
    name, net = country
    assert oracle(client, writer, name, net, cost, 60, seed=2) > 40


@pytest.fixture()
def grid(writer) -> dict:
    """A 30 x 30 grid at a uniform 30 km/h, 100 m blocks (1,740 segments; geodesic lengths
    differ from 100 m by a few per mille, hence the 1 % tolerances)."""
    name = unique("hgrid")
    net = synthetic.grid(writer, name, 30, 30, seed=None)
    writer.execute("UPDATE road_segments SET speed_limit_kph = 30 WHERE network_id = %s", (net,))
    rows = {}
    for sid, r in writer.execute(
            "SELECT s.id, split_part(a.external_id, ':', 1)::int FROM road_segments s "
            "JOIN road_nodes a ON a.id = s.source_node JOIN road_nodes b ON b.id = s.target_node "
            "WHERE s.network_id = %s AND split_part(a.external_id, ':', 1) = "
            "split_part(b.external_id, ':', 1) "
            "ORDER BY split_part(a.external_id, ':', 2)::int", (net,)):
        rows.setdefault(r, []).append(sid)
    corner = writer.execute(
        "SELECT ST_X(geom), ST_Y(geom), external_id FROM road_nodes WHERE network_id = %s "
        "AND external_id IN ('0:0', '0:20') ORDER BY external_id", (net,)).fetchall()
    return {"name": name, "net": net, "rows": rows,
            "points": [(x, y) for x, y, _ in corner]}


@pytest.fixture(params=["hierarchy", "dijkstra"])
def through(request, monkeypatch) -> str:
    """Which search answers: the hierarchy, or Dijkstra alone (the fallback while a hierarchy
    is being built, or for a query from a version the metric has moved past)."""
    if request.param == "dijkstra":
        monkeypatch.setenv("UGVMAP_ROUTING_HIERARCHY_MIN_SEGMENTS", str(10**9))
    routing_settings.cache_clear()
    yield request.param
    routing_settings.cache_clear()


def searcher(client, name: str, net: int, through: str) -> Hierarchy | None:
    """Load the graph and, through the hierarchy, wait until it answers."""
    if through == "hierarchy":
        return hierarchy_ready(client, name, net, Cost.TIME)
    lon, lat = _any_node(net)
    client.get(f"/networks/{name}/route", params={"points": f"{lon},{lat};{lon},{lat}"})
    assert cost_graph(net, Cost.TIME).hierarchy is None
    return None


def test_edits_reach_the_next_route(client, writer, grid, through) -> None:
    """Faster road -> used at once; one-way against the trip -> avoided at once. The very
    next route is exact whichever search answers it (Dijkstra on the patched weights while the
    hierarchy's metric catches up in the background); once caught up, the hierarchy answers
    the same. Each edit is a row patch, never a reload; routes equal pgr_dijkstra after."""
    name, net, row2 = grid["name"], grid["net"], set(grid["rows"][2])
    searcher(client, name, net, through)
    reg = registry(get_settings().database_url)
    loads = reg.stats["loads"]
    body = route(client, name, grid["points"])
    assert not row2 & set(segment_walk(body))  # straight along row 0: 20 x 12 s
    assert body["routes"][0]["duration"] == pytest.approx(240.0, rel=1e-2)

    def next_route(points: list) -> dict:
        """The very next route, then (through the hierarchy) the same once it answers."""
        body = route(client, name, points)  # no waiting: the next request sees the edit
        hierarchy = searcher(client, name, net, through)
        if hierarchy is not None:
            answered = hierarchy.answered
            again = route(client, name, points)
            assert hierarchy.answered == answered + 1
            assert segment_walk(again) == segment_walk(body)
            assert again["routes"][0]["weight"] == pytest.approx(body["routes"][0]["weight"])
        return body

    writer.execute("UPDATE road_segments SET speed_limit_kph = 150 WHERE id = ANY(%s)",
                   (list(row2),))
    body = next_route(grid["points"])
    assert row2 & set(segment_walk(body))
    assert body["routes"][0]["duration"] == pytest.approx(4 * 12 + 20 * 2.4, rel=1e-2)

    writer.execute("UPDATE road_segments SET oneway = 'backward' WHERE id = ANY(%s)",
                   (list(row2),))  # row 2 now runs west only; the trip goes east
    body = next_route(grid["points"])
    assert not row2 & set(segment_walk(body))
    assert body["routes"][0]["duration"] == pytest.approx(240.0, rel=1e-2)
    back = next_route(grid["points"][::-1])  # westbound may use it
    assert row2 & set(segment_walk(back))
    assert reg.stats["loads"] == loads
    if through == "hierarchy":
        assert oracle(client, writer, name, net, Cost.TIME, 30, seed=5) > 25
    else:
        assert check_against_pgrouting(client, writer, name, net, Cost.TIME, 30, seed=5) > 25


def test_geometry_edit_keeps_the_hierarchy(client, writer, grid) -> None:
    """A new geometry with the same end nodes (a detour bulging 300 m north) is a weight
    change: the next route prices the longer segment, the hierarchy is kept, not rebuilt."""
    name, net, fid = grid["name"], grid["net"], grid["rows"][0][10]
    hierarchy = hierarchy_ready(client, name, net, Cost.TIME)
    assert fid in segment_walk(route(client, name, grid["points"]))
    a, b = writer.execute("SELECT ST_AsGeoJSON(ST_StartPoint(geom))::json, "
                          "ST_AsGeoJSON(ST_EndPoint(geom))::json FROM road_segments "
                          "WHERE id = %s", (fid,)).fetchone()
    (x0, y0), (x1, _) = a["coordinates"], b["coordinates"]
    bulge = [[x0, y0], [(x0 + x1) / 2, y0 + 0.0027], b["coordinates"]]
    r = client.patch(f"/collections/{name}-segments/items/{fid}",
                     json={"geometry": {"type": "LineString", "coordinates": bulge}},
                     headers={**bearer("editor"), "If-Match": '"1"'})
    assert r.status_code == 200, r.text
    body = route(client, name, grid["points"])
    assert fid not in segment_walk(body)  # ~600 m now: round the block (2 x 100 m) instead
    assert body["routes"][0]["duration"] == pytest.approx(240.0 + 2 * 12, rel=1e-2)
    assert cost_graph(net, Cost.TIME).hierarchy is hierarchy
    assert oracle(client, writer, name, net, Cost.TIME, 30, seed=7) > 25


def test_edit_sequence_patches_equal_fresh_builds(client, writer, grid, through) -> None:
    """Thirty random edits (speed, class, one-way, lanes, geometry with the same ends), each a
    row patch: every cost model carried along equals one built from scratch on the same rows
    (weights, and the hierarchy's metric), and routes equal pgr_dijkstra afterwards."""
    name, net = grid["name"], grid["net"]
    searcher(client, name, net, through)
    reg = registry(get_settings().database_url)
    for key in ((Cost.TIME, frozenset()), (Cost.DISTANCE, frozenset()),
                (Cost.TIME, frozenset({"service"}))):
        reg._graphs[net].costs(*key)
    loads, patches = reg.stats["loads"], reg.stats["patches"]
    rng = random.Random(4)
    ids = [sid for row in grid["rows"].values() for sid in row]
    bend = ("ST_MakeLine(ARRAY[ST_StartPoint(geom), ST_Translate(ST_Centroid(geom), 0, {}), "
            "ST_EndPoint(geom)])")
    edits = ("speed_limit_kph = {}".format, "road_class = '{}'".format,
             "oneway = '{}'".format, "lanes_forward = {}".format,
             lambda dy: f"geom = {bend.format(dy)}, "  # a vertex off the line, ends kept
                        f"length_m = ST_Length(({bend.format(dy)})::geography)")
    values = ([5, 20, 45, 90, 150], ["service", "primary", "residential"],
              ["forward", "backward", "none"], [1, 3], [-4e-4, -1e-4, 2e-4, 5e-4])
    for _ in range(30):
        k = rng.randrange(len(edits))
        writer.execute(f"UPDATE road_segments SET {edits[k](rng.choice(values[k]))} "
                       "WHERE id = %s", (rng.choice(ids),))
    graph = caught_up(writer, net)
    assert reg.stats["loads"] == loads and reg.stats["patches"] - patches == 30

    with psycopg.connect(dsn(get_settings().database_url), autocommit=True) as conn:
        segs, version = read_segments(conn, net)
    fresh = RoadGraph(net, version, segs, shape=replace(graph.shape, hierarchy=None))
    for (cost, avoid), carried in list(graph._costs.items()):
        built = fresh.costs(cost, avoid)
        np.testing.assert_array_equal(carried.seg_cost, built.seg_cost)
        np.testing.assert_array_equal(carried.arc_costs, built.arc_costs)
        assert carried.max_rate >= built.max_rate
        assert carried.total_cost == pytest.approx(built.total_cost, rel=1e-9)
        if carried.hierarchy is not None:
            metric = metric_at(carried)
            assert metric.version == graph.version
            np.testing.assert_array_equal(metric.weights,
                                          quantise(built.arc_costs, metric.quantum))
    if through == "hierarchy":
        assert oracle(client, writer, name, net, Cost.TIME, 30, seed=8) > 20
    else:
        assert check_against_pgrouting(client, writer, name, net, Cost.TIME, 30, seed=8) > 20


def assert_fresh(writer, net: int) -> None:
    """The registry's graph, patched edit by edit, equals one built from the database now."""
    graph = caught_up(writer, net)
    with psycopg.connect(dsn(get_settings().database_url), autocommit=True) as conn:
        segs, version = read_segments(conn, net)
    assert_same_graph(graph, RoadGraph(net, version, segs,
                                       shape=replace(Shape.of(segs), hierarchy=None)))


def metric_at(cg: CostGraph, timeout_s: float = 30):
    """The hierarchy's metric for the cost graph once it has reached the cost graph's version
    (first customisation and background updates included)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        metric = cg.hierarchy.metric(cg.hierarchy_key, cg.version, cg.arc_costs, cg.max_rate,
                                     wait_s=0.2)
        if metric is not None:
            return metric
        time.sleep(0.02)
    raise AssertionError("the metric did not reach the graph's version")


def caught_up(writer, net: int, timeout_s: float = 10) -> RoadGraph:
    """The registry's graph once notifications alone brought it to the database's version."""
    version = writer.execute("SELECT version FROM networks WHERE id = %s", (net,)).fetchone()[0]
    reg = registry(get_settings().database_url)
    deadline = time.monotonic() + timeout_s
    while reg._graphs[net].version < version and time.monotonic() < deadline:
        time.sleep(0.02)
    assert reg._graphs[net].version == version
    return reg._graphs[net]


def test_topology_edit_falls_back_then_rebuilds(client, writer, grid) -> None:
    """Deleting a segment or splitting one changes the arcs: routes stay exact (Dijkstra) at
    once, and a new hierarchy contracted in the previous order (no new dissection) takes over
    once built; a restarted process with the same arcs loads that order from the data dir."""
    name, net = grid["name"], grid["net"]
    old = hierarchy_ready(client, name, net, Cost.TIME)
    assert old.order_source == "dissected"
    writer.execute("DELETE FROM road_segments WHERE id = ANY(%s)", (grid["rows"][0][5:8],))
    body = route(client, name, grid["points"])
    assert not set(grid["rows"][0][5:8]) & set(segment_walk(body))
    assert body["routes"][0]["duration"] == pytest.approx(240.0 + 2 * 12, rel=1e-2)
    new = hierarchy_ready(client, name, net, Cost.TIME)
    assert new is not old and new.order_source == "derived"
    assert oracle(client, writer, name, net, Cost.TIME, 30, seed=6) > 25

    fid = grid["rows"][0][12]
    r = client.post(f"/collections/{name}-segments/items/{fid}/split", json={"fraction": 0.5},
                    headers={**bearer("admin"), "If-Match": '"1"'})
    assert r.status_code in (200, 201), r.text
    split = hierarchy_ready(client, name, net, Cost.TIME)
    assert split is not new and split.order_source == "derived"
    assert split.order is not None and split.order.added == 1  # the node the split added
    assert_fresh(writer, net)  # spliced around the new node and segment, not rebuilt
    assert oracle(client, writer, name, net, Cost.TIME, 30, seed=9) > 25

    halves = [f["id"] for f in r.json()["features"]]
    tags = ", ".join(client.get(f"/collections/{name}-segments/items/{h}").headers["ETag"]
                     for h in halves)
    r = client.post(f"/collections/{name}-segments/merge", json={"segments": halves},
                    headers={**bearer("admin"), "If-Match": tags})
    assert r.status_code == 200, r.text
    merged = hierarchy_ready(client, name, net, Cost.TIME)  # the arcs of `new` again
    assert merged.order_source == "saved"
    assert_fresh(writer, net)  # the split's node dropped
    assert oracle(client, writer, name, net, Cost.TIME, 20, seed=10) > 15

    restarted = GraphRegistry(get_settings().database_url)  # another process, same data dir
    version = writer.execute("SELECT version FROM networks WHERE id = %s", (net,)).fetchone()[0]
    reloaded = restarted.get(net, version).costs(Cost.TIME).hierarchy
    assert reloaded is not None and reloaded is not split
    assert reloaded.ready.wait(60) and reloaded.order_source == "saved"
    np.testing.assert_array_equal(reloaded.order.node_ids, merged.order.node_ids)
