"""What the hostile probe of issue 33 found about writes (editing the network), each shown
failing before its fix: a history that could not be read back, deep ``attrs`` answered 500,
segment ends one ULP off their nodes, deadlocks answered as a database outage, a
self-contradicting message, QGIS's numeric strings refused, and the routing graph's live patch
crashing on a deleted isolated segment."""

from __future__ import annotations

import threading

import httpx
import psycopg
import pytest
from click.testing import CliRunner
from sqlalchemy import text
from sqlalchemy.exc import OperationalError

from app.api.errors import database_unavailable
from app.db.session import TRIES, retried, session_scope
from app.errors import ConflictError
from app.network.validation import MAX_ATTRS_DEPTH
from app.routing.graph import RoadGraph
from app.routing.live import read_segments
from cli.main import main
from ingest.network import RoadAttributes, RoadLine, write_network
from testkit import synthetic
from testkit.network_helpers import bearer, grid_network
from tests.routing_support import dsn, unique, xy
from tests.test_routing_live import assert_same_graph


@pytest.fixture(scope="module")
def writer(database_url: str):
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        yield conn


def test_deleting_an_isolated_segment_is_patched_into_the_graph(writer, database_url) -> None:
    """Item 7: the patch had no fresh rows, and the empty list of their places became a float
    array, so ``Layout.of`` sliced with floats (``slice indices must be integers``) and the
    listener fell back to reloading the whole network."""
    net = synthetic.create_network(writer, unique("isolated"))
    synthetic.add_line(writer, net, [xy(0, 0), xy(100, 0)])
    synthetic.add_line(writer, net, [xy(100, 0), xy(200, 0)])
    lonely = synthetic.add_line(writer, net, [xy(0, 500), xy(100, 500)])
    with psycopg.connect(dsn(database_url)) as conn:
        before, version = read_segments(conn, net)
        graph = RoadGraph(net, version, before)
        writer.execute("DELETE FROM road_segments WHERE id = %s", (lonely,))
        box = [*xy(0, 500), *xy(100, 500)]
        fresh, _ = read_segments(conn, net, [box[0], box[1], box[2], box[3]])
        assert len(fresh) == 0
        patched = graph.patched(version + 1, box, fresh)
        after, _ = read_segments(conn, net)
    assert lonely not in patched.segs.ids
    assert_same_graph(patched, RoadGraph(net, version + 1, after))


def nested(depth: int) -> dict:
    """An ``attrs`` object nested ``depth`` objects deep: {"a": {"a": ... {"a": 1}}}."""
    value: object = 1
    for _ in range(depth):
        value = {"a": value}
    assert isinstance(value, dict)
    return value


def nested_text(depth: int) -> str:
    return '{"a": ' * depth + "1" + "}" * depth


@pytest.fixture()
def grid(client):
    net = grid_network()
    return net, f"/collections/{net.network}-segments/items"


def first_segment(client, items: str) -> dict:
    return client.get(items, params={"limit": 1}).json()["features"][0]


@pytest.mark.parametrize(("method", "attrs"), [
    ("PATCH", nested(260)),            # item 1: stored, then its history could not be read
    ("PATCH", nested(800)),            # item 5: RecursionError in the rule check -> 500
    ("PUT", nested(800)),
    ("PATCH", nested_text(3000)),      # item 5: JSON text too deep for the parser -> 500
    ("PUT", nested_text(3000)),
])
def test_attrs_too_deep_to_store_and_read_back_are_refused(client, grid, method,
                                                          attrs) -> None:
    _, items = grid
    feature = first_segment(client, items)
    fid = feature["id"]
    body = {"attrs": attrs} if method == "PATCH" else {
        "type": "Feature", "geometry": feature["geometry"], "properties": {"attrs": attrs}}
    r = client.request(method, f"{items}/{fid}", json=body, headers=bearer("editor"))
    assert (r.status_code, r.json()["code"]) == (422, "InvalidValue"), r.text[:300]
    assert f"at most {MAX_ATTRS_DEPTH} levels" in r.json()["errors"]["attrs"]
    after = client.get(f"{items}/{fid}").json()
    assert after["properties"]["version"] == 1 and after["properties"]["attrs"] == {}
    history = client.get(f"{items}/{fid}/history")
    assert history.status_code == 200 and history.json()["edits"] == []


def test_attrs_at_the_depth_limit_are_stored_and_read_back(client, grid) -> None:
    _, items = grid
    fid = first_segment(client, items)["id"]
    deepest = nested(MAX_ATTRS_DEPTH)
    r = client.patch(f"{items}/{fid}", json={"attrs": deepest}, headers=bearer("editor"))
    assert r.status_code == 200, r.text
    assert client.get(f"{items}/{fid}").json()["properties"]["attrs"] == deepest
    edits = client.get(f"{items}/{fid}/history").json()["edits"]
    assert edits[-1]["new"] == {"attrs": deepest}


def test_a_history_row_stored_before_the_limit_is_still_readable(client, grid) -> None:
    """Item 1's second half: rows written before the depth limit (260 deep attrs) made
    ``GET .../history`` a plain-text 500 for good; the history is served as PostgreSQL
    writes it, so any stored row reads back, exactly."""
    net, items = grid
    fid = first_segment(client, items)["id"]
    with session_scope() as s:
        s.execute(text(
            "INSERT INTO segment_edits (network_id, segment_id, action, version_from, "
            "version_to, edited_by, conditional, old, new) VALUES (:n, :s, 'update', 1, 2, "
            "'probe', false, CAST(:old AS jsonb), CAST(:new AS jsonb))"),
            {"n": net.network_id, "s": fid, "old": '{"attrs": {}}',
             "new": '{"attrs": ' + nested_text(260) + "}"})
    r = client.get(f"{items}/{fid}/history")
    assert r.status_code == 200, r.text[:300]
    edits = r.json()["edits"]
    assert [e["action"] for e in edits] == ["update"]
    assert edits[0]["new"] == {"attrs": nested(260)} and edits[0]["old"] == {"attrs": {}}
    assert edits[0]["edited_by"] == "probe" and edits[0]["conditional"] is False
    assert (edits[0]["version_from"], edits[0]["version_to"]) == (1, 2)


def validate(network: str) -> str:
    """``ugvmap network validate``, which must find the network clean."""
    result = CliRunner().invoke(main, ["network", "validate", network])
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture()
def cross(client):
    """Two streets crossing at a junction (1.642, 42.414) in Andorra, where 15 decimals of
    a longitude (1.6...) are 16 significant digits: one short of every double."""
    name = unique("cross")
    with session_scope() as s:
        write_network(s, name, [
            RoadLine([(1.640, 42.414), (1.642, 42.414), (1.644, 42.414)], RoadAttributes()),
            RoadLine([(1.642, 42.412), (1.642, 42.414), (1.642, 42.416)], RoadAttributes())])
    return name


def test_a_created_segment_ends_on_its_nodes_to_the_last_bit(client, cross) -> None:
    """Item 2: the nodes kept the exact doubles, the line's ends were the nodes read back as
    text with 15 decimals, one ULP away: ``validate`` then said "segment ends away from its
    nodes"."""
    r = client.post(f"/collections/{cross}-segments/items", headers=bearer("editor"), json={
        "type": "Feature", "properties": {}, "geometry": {
            "type": "LineString",
            "coordinates": [[1.6500000000000001, 42.43], [1.651, 42.4300000000000001]]}})
    assert r.status_code == 201, r.text
    validate(cross)


@pytest.mark.parametrize("then", ["geometry", "split", "merge"])
def test_edits_after_moving_a_node_to_an_odd_double_keep_the_ends_on_it(client, cross,
                                                                        then) -> None:
    """Item 2: a node PATCHed to a position 15 decimals cannot write, then a geometry PATCH
    or a split of one of its segments (or a merge through another node) put a line end
    one ULP off the node."""
    nodes, segments = (f"/collections/{cross}-{k}/items" for k in ("nodes", "segments"))
    junction = next(f for f in client.get(nodes).json()["features"]
                    if f["properties"]["kind"] == "junction")
    admin = bearer("admin")
    r = client.patch(f"{nodes}/{junction['id']}", headers=admin, json={
        "geometry": {"type": "Point", "coordinates": [1.6420000000000001, 42.414000000000004]}})
    assert r.status_code == 200, r.text
    validate(cross)
    west = next(f for f in client.get(segments).json()["features"]
                if f["geometry"]["coordinates"][0] == [1.64, 42.414])
    coords = west["geometry"]["coordinates"]
    if then == "geometry":
        bent = [coords[0], [1.641, 42.4141], coords[-1]]
        r = client.patch(f"{segments}/{west['id']}", headers=admin,
                         json={"geometry": {"type": "LineString", "coordinates": bent}})
    elif then == "split":
        r = client.post(f"{segments}/{west['id']}/split", headers=admin, json={"fraction": 0.3})
    else:
        split = client.post(f"{segments}/{west['id']}/split", headers=admin,
                            json={"fraction": 0.3})
        assert split.status_code == 200, split.text
        r = client.post(f"/collections/{cross}-segments/merge", headers=admin, json={
            "segments": [f["id"] for f in split.json()["features"]]})
    assert r.status_code == 200, r.text
    validate(cross)


def node_and_segments(network_id: int, lon: float, lat: float) -> tuple[int, list[int]]:
    """The node at (lon, lat) and its segments' ids, ascending."""
    with session_scope() as s:
        node = s.execute(text("SELECT id FROM road_nodes WHERE network_id = :n AND "
                              "geom ~= ST_SetSRID(ST_MakePoint(:x, :y), 4326)"),
                         {"n": network_id, "x": lon, "y": lat}).scalar_one()
        ids = s.execute(text("SELECT id FROM road_segments WHERE source_node = :v OR "
                             "target_node = :v ORDER BY id"), {"v": node}).scalars().all()
    return node, list(ids)


def wait_for_waiters(watcher: psycopg.Connection, count: int) -> None:
    """Block until ``count`` sessions of this database wait on a lock (the server's requests
    got as far as the interleaving needs); a bounded wait that fails loudly, no sleeping."""
    for _ in range(3000):
        waiting = watcher.execute(
            "SELECT count(*) FROM pg_stat_activity WHERE datname = current_database() "
            "AND wait_event_type = 'Lock'").fetchone()
        if waiting is not None and waiting[0] >= count:
            return
        watcher.execute("SELECT pg_sleep(0.01)")
    raise AssertionError(f"{count} requests never reached their lock waits")


def in_thread(send) -> tuple[threading.Thread, list]:
    answers: list = []
    thread = threading.Thread(target=lambda: answers.append(send()))
    thread.start()
    return thread, answers


def test_a_node_move_racing_a_deletion_of_its_segment_does_not_deadlock(
        live_server, database_url) -> None:
    """Item 3: the move locked the node, then the network's topology lock, then the node's
    segments; the deletion locked its segment, then its nodes. Held apart at the topology
    lock (a third session holds it) until both are in flight, the two deadlocked and the
    loser was told 503 ``DatabaseUnavailable: deadlock detected``. Every edit now takes the
    network's edit lock first, so they run one after the other."""
    net = grid_network()
    centre, segments = node_and_segments(net.network_id, 10.001, 50.001)
    nodes = f"{live_server}/collections/{net.network}-nodes/items"
    items = f"{live_server}/collections/{net.network}-segments/items"
    admin = bearer("admin")
    with psycopg.connect(dsn(database_url)) as blocker, \
            psycopg.connect(dsn(database_url), autocommit=True) as watcher:
        blocker.execute("SELECT pg_advisory_xact_lock(hashtext('ugvmap.topology'), %s)",
                        (net.network_id,))
        move, moved = in_thread(lambda: httpx.patch(f"{nodes}/{centre}", json={
            "geometry": {"type": "Point", "coordinates": [10.00101, 50.00102]}},
            headers=admin, timeout=60))
        wait_for_waiters(watcher, 1)
        delete, deleted = in_thread(lambda: httpx.delete(f"{items}/{segments[0]}",
                                                         headers=admin, timeout=60))
        wait_for_waiters(watcher, 2)
        blocker.commit()
        move.join(60)
        delete.join(60)
    assert (moved[0].status_code, deleted[0].status_code) == (200, 204), \
        (moved[0].text, deleted[0].text)
    validate(net.network)


def test_a_node_deletion_after_its_segment_went_says_what_changed(live_server,
                                                                  database_url) -> None:
    """Item 13: a node DELETE that waited for a DELETE of one of its two segments answered
    "node joins 2 segment ends: only a node between two segments can be deleted", its degree
    read before the wait. It now says what it found once it holds the locks."""
    net = grid_network()
    corner, (row0, _) = node_and_segments(net.network_id, 10.0, 50.0)
    nodes = f"{live_server}/collections/{net.network}-nodes/items"
    items = f"{live_server}/collections/{net.network}-segments/items"
    admin = bearer("admin")
    with psycopg.connect(dsn(database_url)) as blocker, \
            psycopg.connect(dsn(database_url), autocommit=True) as watcher:
        blocker.execute("SELECT id FROM road_nodes WHERE id = %s FOR UPDATE", (corner,))
        delete_segment, segment_answer = in_thread(
            lambda: httpx.delete(f"{items}/{row0}", headers=admin, timeout=60))
        wait_for_waiters(watcher, 1)
        delete_node, node_answer = in_thread(
            lambda: httpx.delete(f"{nodes}/{corner}", headers=admin, timeout=60))
        wait_for_waiters(watcher, 2)
        blocker.commit()
        delete_segment.join(60)
        delete_node.join(60)
    assert segment_answer[0].status_code == 204, segment_answer[0].text
    refused = node_answer[0]
    assert refused.status_code == 422, refused.text
    message = refused.json()["errors"]["id"]
    assert f"node {corner} joins 1 segment end" in message, message
    assert "2 segment" not in message
    validate(net.network)


RAISE_DEADLOCK = ("DO $$ BEGIN RAISE EXCEPTION 'deadlock detected' USING ERRCODE = '40P01'; "
                  "END $$")


def test_a_write_that_lost_a_deadlock_is_tried_again() -> None:
    """Item 3's safety net: PostgreSQL's deadlock_detected (raised for real by the server)
    rolls the transaction back, which then runs again from the start."""
    tries: list[int] = []

    def work(session) -> int:
        tries.append(1)
        session.execute(text("CREATE TEMP TABLE IF NOT EXISTS probe_retry (x int)"))
        if len(tries) == 1:
            session.execute(text(RAISE_DEADLOCK))
        return int(session.execute(text("SELECT 7")).scalar_one())

    assert retried(work) == 7 and len(tries) == 2


def test_a_write_that_keeps_losing_is_a_conflict_not_an_outage() -> None:
    """After :data:`TRIES` lost races the write is a 409 ``Conflict`` saying nothing was
    changed; a deadlock met anywhere else is a 409 too, never 503 ``DatabaseUnavailable``."""
    tries: list[int] = []

    def work(session) -> None:
        tries.append(1)
        session.execute(text(RAISE_DEADLOCK))

    with pytest.raises(ConflictError, match="nothing was changed"):
        retried(work)
    assert len(tries) == TRIES
    with pytest.raises(OperationalError) as lost, session_scope() as s:
        s.execute(text(RAISE_DEADLOCK))
    answer = database_unavailable(None, lost.value)
    assert answer.status_code == 409 and b'"code":"Conflict"' in answer.body


@pytest.mark.parametrize("method", ["PATCH", "PUT"])
def test_numbers_sent_as_text_by_qgis_are_read_as_numbers(client, grid, method) -> None:
    """Item 14: QGIS 3.40 typed ``width_m`` String (the first page's values were all null)
    and sent ``"3.5"``, refused with 422 "must be a number". Number text in JSON's own
    syntax now reads as that number; anything else is still refused, with nothing stored."""
    _, items = grid
    feature = first_segment(client, items)
    url = f"{items}/{feature['id']}"

    def send(properties: dict) -> httpx.Response:
        body = {"properties": properties} if method == "PATCH" else {
            "type": "Feature", "geometry": feature["geometry"],
            "properties": {**feature["properties"], **properties}}
        return client.request(method, url, json=body, headers=bearer("editor"))

    r = send({"width_m": "3.5", "speed_limit_kph": "42", "lanes_forward": "3"})
    assert r.status_code == 200, r.text
    props = client.get(url).json()["properties"]
    assert (props["width_m"], props["speed_limit_kph"], props["lanes_forward"]) == (3.5, 42, 3)
    assert isinstance(props["lanes_forward"], int)
    for bad in ({"width_m": "3,5"}, {"width_m": " 3.5"}, {"width_m": "1e400"},
                {"width_m": "0x10"}, {"lanes_forward": "2.0"}, {"width_m": "\u0663"}):
        refused = send(bad)
        assert (refused.status_code, refused.json()["code"]) == (422, "InvalidValue"), bad
    assert client.get(url).json()["properties"]["version"] == 2
