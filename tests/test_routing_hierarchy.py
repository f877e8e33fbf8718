"""Routes through the contraction hierarchy equal ``pgr_dijkstra``, before and after live edits.

Networks here are above ``hierarchy_min_segments`` (1000), so once the hierarchy is built the
route endpoint answers through it; each test waits for that and checks the hierarchy did
answer (its ``answered`` counter), so a silent fallback to Dijkstra would fail them.
"""

from __future__ import annotations

import time

import psycopg
import pytest

from app.db.session import session_scope
from app.routing import synthetic
from app.routing.costs import Cost
from app.routing.graph import CostGraph
from app.routing.hierarchy import Hierarchy
from app.routing.live import registry
from app.routing.synthetic_osm import write_country
from app.settings import get_settings
from tests.routing_support import dsn, route, segment_walk, unique
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


def test_edits_reach_the_hierarchy_routes(client, writer, grid) -> None:
    """Faster road -> used at once; one-way against the trip -> avoided at once; each
    answered by the hierarchy (partial customisation), each equal to pgr_dijkstra."""
    name, net, row2 = grid["name"], grid["net"], set(grid["rows"][2])
    hierarchy = hierarchy_ready(client, name, net, Cost.TIME)
    body = route(client, name, grid["points"])
    assert not row2 & set(segment_walk(body))  # straight along row 0: 20 x 12 s
    assert body["routes"][0]["duration"] == pytest.approx(240.0, rel=1e-2)

    answered = hierarchy.answered
    writer.execute("UPDATE road_segments SET speed_limit_kph = 150 WHERE id = ANY(%s)",
                   (list(row2),))
    body = route(client, name, grid["points"])  # no waiting: the next request sees it
    assert row2 & set(segment_walk(body))
    assert body["routes"][0]["duration"] == pytest.approx(4 * 12 + 20 * 2.4, rel=1e-2)
    assert hierarchy.answered == answered + 1

    writer.execute("UPDATE road_segments SET oneway = 'backward' WHERE id = ANY(%s)",
                   (list(row2),))  # row 2 now runs west only; the trip goes east
    body = route(client, name, grid["points"])
    assert not row2 & set(segment_walk(body))
    assert body["routes"][0]["duration"] == pytest.approx(240.0, rel=1e-2)
    assert hierarchy.answered == answered + 2
    back = route(client, name, grid["points"][::-1])  # westbound may use it
    assert row2 & set(segment_walk(back))
    assert oracle(client, writer, name, net, Cost.TIME, 30, seed=5) > 25


def test_topology_edit_falls_back_then_rebuilds(client, writer, grid) -> None:
    """Deleting a segment changes the arcs: routes stay exact (Dijkstra) at once, and a new
    hierarchy takes over once built."""
    name, net = grid["name"], grid["net"]
    old = hierarchy_ready(client, name, net, Cost.TIME)
    writer.execute("DELETE FROM road_segments WHERE id = ANY(%s)", (grid["rows"][0][5:8],))
    body = route(client, name, grid["points"])
    assert not set(grid["rows"][0][5:8]) & set(segment_walk(body))
    assert body["routes"][0]["duration"] == pytest.approx(240.0 + 2 * 12, rel=1e-2)
    new = hierarchy_ready(client, name, net, Cost.TIME)
    assert new is not old
    assert oracle(client, writer, name, net, Cost.TIME, 30, seed=6) > 25
