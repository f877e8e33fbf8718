"""Edits reach the routing graph: the next route query after a commit reflects it.

Covers the NOTIFY-driven patch (the patched graph equals a fresh load) and the per-request
version check, in-process and across two server workers.
"""

from __future__ import annotations

import os
import time

import httpx
import numpy as np
import psycopg
import pytest

from app.routing import live
from app.routing.costs import Cost
from app.routing.graph import RoadGraph
from app.routing.live import read_segments, registry
from app.settings import get_settings
from testkit import synthetic
from testkit.network_helpers import bearer
from testkit.server import running_server
from tests.routing_support import dsn, route, segment_walk, unique
from tests.routing_support import xy as xy0


def xy(x_m: float, y_m: float) -> tuple[float, float]:
    return xy0(x_m, y_m, origin=(1.6, 42.5))


@pytest.fixture(scope="module")
def writer(database_url: str):
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        yield conn


@pytest.fixture()
def ring(writer) -> dict:
    """West and east streets joined by a south (30 km/h) and a north (20 km/h) street.

    From the middle of the west street to the middle of the east street both ways are 300 m;
    the time-optimal one is south until an edit says otherwise.
    """
    name = unique("ring")
    net = synthetic.create_network(writer, name)
    add = synthetic.add_line
    seg = {
        "s": add(writer, net, [xy(0, 0), xy(200, 0)], speed_limit_kph=30),
        "n": add(writer, net, [xy(0, 100), xy(200, 100)], speed_limit_kph=20),
        "w": add(writer, net, [xy(0, 0), xy(0, 100)], speed_limit_kph=30),
        "e": add(writer, net, [xy(200, 0), xy(200, 100)], speed_limit_kph=30),
    }
    return {"name": name, "net": net, "seg": seg, "points": [xy(-3, 50), xy(203, 50)]}


def test_raising_a_speed_limit_changes_the_next_route(client, writer, ring) -> None:
    seg = ring["seg"]
    assert seg["s"] in segment_walk(route(client, ring["name"], ring["points"]))
    writer.execute("UPDATE road_segments SET speed_limit_kph = 60 WHERE id = %s", (seg["n"],))
    body = route(client, ring["name"], ring["points"])
    assert segment_walk(body) == [seg["w"], seg["n"], seg["e"]]
    assert body["routes"][0]["legs"][0]["steps"][1]["speed_limit_kph"] == 60


def test_making_a_segment_one_way_changes_the_next_route(client, writer, ring) -> None:
    seg = ring["seg"]
    assert seg["s"] in segment_walk(route(client, ring["name"], ring["points"], cost="time"))
    # The south street now runs westbound only (against its geometry).
    writer.execute("UPDATE road_segments SET oneway = 'backward' WHERE id = %s", (seg["s"],))
    assert segment_walk(route(client, ring["name"], ring["points"])) == [seg["w"], seg["n"],
                                                                         seg["e"]]
    back = route(client, ring["name"], ring["points"][::-1])
    assert seg["s"] in segment_walk(back)


def patch_segment(http, network: str, fid: int, version: int, **props) -> None:
    """Edit a segment through the OGC API Features PATCH endpoint, as the web editor does."""
    r = http.patch(f"/collections/{network}-segments/items/{fid}", json=props,
                   headers={**bearer("editor"), "If-Match": f'"{version}"'})
    assert r.status_code == 200, r.text


def test_patch_edits_change_the_next_route(client, ring) -> None:
    seg = ring["seg"]
    assert seg["s"] in segment_walk(route(client, ring["name"], ring["points"]))
    patch_segment(client, ring["name"], seg["s"], 1, oneway="backward")
    assert segment_walk(route(client, ring["name"], ring["points"])) == [seg["w"], seg["n"],
                                                                         seg["e"]]
    patch_segment(client, ring["name"], seg["s"], 2, oneway="none", speed_limit_kph=90)
    assert seg["s"] in segment_walk(route(client, ring["name"], ring["points"]))


def test_listener_patch_equals_fresh_load(client, writer, ring, database_url) -> None:
    """Insert, move, re-attribute and delete segments; the patched graph is a fresh load."""
    route(client, ring["name"], ring["points"])  # graph loaded, listener running
    reg = registry(get_settings().database_url)
    patches = reg.stats["patches"]
    seg, net = ring["seg"], ring["net"]
    synthetic.add_line(writer, net, [xy(0, 100), xy(100, 150), xy(200, 100)], oneway="forward")
    writer.execute("UPDATE road_segments SET geom = ST_GeomFromText(%s, 4326), lanes_forward = 3 "
                   "WHERE id = %s", (f"LINESTRING({xy(0, 0)[0]} {xy(0, 0)[1]}, "
                                     f"{xy(100, -20)[0]} {xy(100, -20)[1]}, "
                                     f"{xy(200, 0)[0]} {xy(200, 0)[1]})", seg["s"]))
    writer.execute("DELETE FROM road_segments WHERE id = %s", (seg["e"],))
    writer.execute("UPDATE road_segments SET speed_limit_kph = 45, oneway = 'backward' "
                   "WHERE id = %s", (seg["w"],))  # attributes only: the shape is reused
    version = writer.execute("SELECT version FROM networks WHERE id = %s", (net,)).fetchone()[0]
    deadline = time.monotonic() + 5
    while reg._graphs[net].version < version and time.monotonic() < deadline:
        time.sleep(0.02)
    graph = reg._graphs[net]
    assert graph.version == version  # caught up by notifications alone, no request needed
    assert reg.stats["patches"] - patches == 4  # one bounding-box patch per statement
    with psycopg.connect(dsn(database_url)) as conn:
        fresh, _ = read_segments(conn, net)
    for field in ("ids", "source", "target", "oneway", "lanes_forward", "speed_limit",
                  "offsets", "coords"):
        np.testing.assert_array_equal(getattr(graph.segs, field), getattr(fresh, field))
    assert seg["e"] not in graph.segs.ids
    assert_same_graph(graph, RoadGraph(net, version, fresh))


def assert_same_graph(patched: RoadGraph, built: RoadGraph) -> None:
    """Everything a patched graph derives (nodes, arcs, geometry, costs) equals a fresh build
    (parallel arcs may be listed in another order: same key, compared as sets)."""
    for name in ("node_ids", "u", "v", "bbox", "bearing_start", "bearing_end", "speed_kph"):
        np.testing.assert_array_equal(getattr(patched, name), getattr(built, name), name)
    # Fractions come from a running sum over all vertices: equal to rounding.
    np.testing.assert_allclose(patched.fracs, built.fracs, rtol=0, atol=1e-12)
    a, b = patched.shape.arcs, built.shape.arcs
    oa, ob = (np.lexsort((arcs.way, arcs.row, arcs.key)) for arcs in (a, b))
    for name in ("tail", "head", "row", "way", "key"):
        np.testing.assert_array_equal(getattr(a, name)[oa], getattr(b, name)[ob], name)
    np.testing.assert_array_equal(a.indptr, b.indptr)
    for arcs in (a, b):  # each row's arcs point back at it
        for col, way in ((0, 1), (1, -1)):
            has = arcs.by_row[:, col] >= 0
            assert (arcs.row[arcs.by_row[has, col]] == np.flatnonzero(has)).all()
            assert (arcs.way[arcs.by_row[has, col]] == way).all()
    for cost in Cost:
        np.testing.assert_array_equal(np.sort(patched.costs(cost).arc_costs),
                                      np.sort(built.costs(cost).arc_costs))


@pytest.mark.slow
def test_edit_is_seen_by_every_worker(database_url, writer, ring) -> None:
    env = {"DATABASE_URL": database_url, "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"]}
    q = ";".join(f"{lon!r},{lat!r}" for lon, lat in ring["points"])
    seg = ring["seg"]

    def walks(base: str) -> list[list[int]]:
        out = []
        for _ in range(8):  # enough requests to land on both workers
            r = httpx.get(f"{base}/networks/{ring['name']}/route", params={"points": q})
            assert r.status_code == 200, r.text
            out.append(segment_walk(r.json()))
        return out

    with running_server(env, workers=2) as base, httpx.Client(base_url=base) as http:
        assert all(seg["s"] in w for w in walks(base))
        patch_segment(http, ring["name"], seg["n"], 1, speed_limit_kph=80)
        assert all(w == [seg["w"], seg["n"], seg["e"]] for w in walks(base))
        writer.execute("UPDATE road_segments SET oneway = 'backward' WHERE id = %s",
                       (seg["n"],))  # any committed change counts, not only the API's
        assert all(seg["s"] in w for w in walks(base))


def test_request_waits_for_a_slow_patch_instead_of_reloading(client, writer, ring,
                                                             monkeypatch) -> None:
    """A patch slower than the catch-up timeout (a topology change on a country takes about a
    second) is waited for while it runs: the request takes the patched graph, it does not
    read the whole network again."""
    seg = ring["seg"]
    route(client, ring["name"], ring["points"])  # loaded, listener running
    reg = registry(get_settings().database_url)
    monkeypatch.setattr(live, "CATCH_UP_TIMEOUT_S", 0.1)
    patched = RoadGraph.patched

    def slow(self, *args):
        time.sleep(0.6)
        return patched(self, *args)

    monkeypatch.setattr(RoadGraph, "patched", slow)
    loads, waited = reg.stats["loads"], reg.stats["waited"]
    writer.execute("UPDATE road_segments SET speed_limit_kph = 90 WHERE id = %s", (seg["n"],))
    assert segment_walk(route(client, ring["name"], ring["points"])) == [seg["w"], seg["n"],
                                                                         seg["e"]]
    assert reg.stats["loads"] == loads and reg.stats["waited"] == waited


def test_a_plan_made_while_the_version_is_read_is_redone_when_the_graph_is_behind(
        client, writer, ring, monkeypatch) -> None:
    """Quick routes are planned while the database answers the version read, on the graph the
    process holds (app.routing.router._answer). When that graph turns out older than the
    version read (here: the edit's notification as if it had not arrived), that plan is not
    answered: the request plans again on the graph at the version read."""
    from app.routing import router

    seg = ring["seg"]
    assert seg["s"] in segment_walk(route(client, ring["name"], ring["points"]))
    reg = registry(get_settings().database_url)
    before = reg.current(ring["net"], 0)
    assert before is not None
    writer.execute("UPDATE road_segments SET speed_limit_kph = 60 WHERE id = %s", (seg["n"],))
    assert seg["n"] in segment_walk(route(client, ring["name"], ring["points"]))
    with reg._changed:
        reg._graphs[ring["net"]] = before  # the process's graph is behind the database again
    monkeypatch.setattr(live, "CATCH_UP_TIMEOUT_S", 0.1)  # the listener has nothing to send
    early = []
    plan_early = router._plan_early

    def spied(*args):
        early.append(plan_early(*args))
        return early[-1]

    monkeypatch.setattr(router, "_plan_early", spied)
    assert segment_walk(route(client, ring["name"], ring["points"])) == [seg["w"], seg["n"],
                                                                         seg["e"]]
    assert early[-1] is not None and early[-1].version == before.version
    assert reg.current(ring["net"], 0).version > before.version  # reloaded
    assert segment_walk(route(client, ring["name"], ring["points"])) == [seg["w"], seg["n"],
                                                                         seg["e"]]
