"""Topology validation, and admin split/merge keeping the topology valid."""

from __future__ import annotations

import json
import uuid

import pytest
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from ingest.network import RoadAttributes, RoadLine, write_network
from testkit.network_helpers import bearer, grid_network


def _validate(network: str) -> tuple[int, str]:
    result = CliRunner().invoke(main, ["network", "validate", network])
    return result.exit_code, result.output


def test_clean_network_validates(database_url: str) -> None:
    net = grid_network()
    code, out = _validate(net.network)
    assert code == 0, out
    assert "12 segments, 9 nodes, 0 dead ends, 1 connected components" in out


def test_broken_invariants_are_reported(database_url: str) -> None:
    net = grid_network()
    with session_scope() as s:
        node = s.execute(text(  # the centre of the grid, where 4 segments meet
            "SELECT id FROM road_nodes WHERE network_id = :n AND "
            "ST_DWithin(geom, ST_SetSRID(ST_MakePoint(10.001, 50.001), 4326), 1e-9)"),
            {"n": net.network_id}).scalar_one()
        s.execute(text("UPDATE road_nodes SET geom = ST_Translate(geom, 0.0001, 0), "
                       "kind = 'endpoint' WHERE id = :id"), {"id": node})
    code, out = _validate(net.network)
    assert code == 1
    assert "segment ends away from its nodes: 4" in out
    assert f"node kind does not match its degree: 1 (ids {node})" in out
    assert _validate("no-such-network")[0] == 1


def _split(client, network: str, fid: int, body: dict, version: int = 1, role: str = "admin"):
    return client.post(f"/collections/{network}-segments/items/{fid}/split", json=body,
                       headers={**bearer(role), "If-Match": f'"{version}"'})


def test_split_then_merge_keeps_topology(client) -> None:
    net = grid_network()
    items = f"/collections/{net.network}-segments/items"
    original = client.get(items, params={"limit": 1}).json()["features"][0]
    fid = original["id"]
    assert _split(client, net.network, fid, {"fraction": 0.5}, role="editor").status_code == 403
    assert _split(client, net.network, fid, {"fraction": 0.5}, version=5).status_code == 412
    assert _split(client, net.network, fid, {"fraction": 1.0}).status_code == 422
    r = _split(client, net.network, fid, {"point": [10.0004, 50.00001]})
    assert r.status_code == 200, r.text
    first, second = r.json()["features"]
    assert first["id"] == fid and first["properties"]["version"] == 2
    assert first["geometry"]["coordinates"][-1] == second["geometry"]["coordinates"][0]
    assert first["geometry"]["coordinates"][-1] == pytest.approx([10.0004, 50.0])
    assert first["properties"]["length_m"] + second["properties"]["length_m"] == \
        pytest.approx(original["properties"]["length_m"], rel=1e-9)
    assert second["properties"]["name"] == original["properties"]["name"]
    assert _validate(net.network)[0] == 0
    assert client.get(items).json()["numberMatched"] == 13

    # Merging through a junction (three or more segments meet) would break the topology: the
    # split's second half ends at one.
    junction_pair = [second["id"], _neighbour_at_junction(net.network_id, second["id"])]
    r = client.post(f"/collections/{net.network}-segments/merge",
                    json={"segments": junction_pair},
                    headers={**bearer("admin"), "If-Match": '"1", "1"'})
    assert r.status_code == 422, r.text
    r = client.post(f"/collections/{net.network}-segments/merge",
                    json={"segments": [fid, second["id"]]},
                    headers={**bearer("admin"), "If-Match": '"2", "1"'})
    assert r.status_code == 200, r.text
    merged = r.json()
    assert merged["id"] == fid
    assert merged["geometry"]["coordinates"][0] == original["geometry"]["coordinates"][0]
    assert merged["geometry"]["coordinates"][-1] == original["geometry"]["coordinates"][-1]
    assert merged["properties"]["target_node"] == original["properties"]["target_node"]
    assert merged["properties"]["length_m"] == pytest.approx(original["properties"]["length_m"])
    assert client.get(items).json()["numberMatched"] == 12
    code, out = _validate(net.network)
    assert code == 0 and ", 9 nodes," in out
    actions = [e["action"] for e in client.get(f"{items}/{fid}/history").json()["edits"]]
    assert actions == ["split", "merge"]


def _neighbour_at_junction(network_id: int, fid: int) -> int:
    with session_scope() as s:
        return s.execute(text(
            "SELECT b.id FROM road_segments a JOIN road_segments b ON b.id <> a.id AND "
            "b.network_id = a.network_id AND (b.source_node IN (a.source_node, a.target_node) "
            "OR b.target_node IN (a.source_node, a.target_node)) "
            "JOIN road_nodes n ON n.id IN (a.source_node, a.target_node) "
            " AND n.id IN (b.source_node, b.target_node) AND n.kind = 'junction' "
            "WHERE a.id = :id ORDER BY b.id LIMIT 1"), {"id": fid}).scalar_one()


def test_merge_of_opposite_digitised_one_ways(client) -> None:
    """A (0,0)->(1,0) forward and B (2,0)->(1,0) backward are one road flowing +x."""
    name = f"flip-{uuid.uuid4().hex[:8]}"
    lines = [RoadLine([(5.0, 5.0), (5.001, 5.0)], RoadAttributes(2, 0, 40.0, "forward")),
             RoadLine([(5.002, 5.0), (5.001, 5.0)], RoadAttributes(0, 2, 40.0, "backward"))]
    with session_scope() as s:
        write_network(s, name, lines, node_crossings=False)
    items = client.get(f"/collections/{name}-segments/items").json()["features"]
    ids = sorted(f["id"] for f in items)
    r = client.post(f"/collections/{name}-segments/merge", json={"segments": ids},
                    headers={**bearer("admin"), "If-Match": '"1", "1"'})
    assert r.status_code == 200, r.text
    props = r.json()["properties"]
    assert r.json()["geometry"]["coordinates"] == [[5.0, 5.0], [5.001, 5.0], [5.002, 5.0]]
    assert (props["oneway"], props["lanes_forward"], props["lanes_backward"]) == \
        ("forward", 2, 0)
    assert _validate(name)[0] == 0


def test_merge_refuses_different_attributes(client) -> None:
    name = f"diff-{uuid.uuid4().hex[:8]}"
    lines = [RoadLine([(6.0, 5.0), (6.001, 5.0)], RoadAttributes(name="A")),
             RoadLine([(6.001, 5.0), (6.002, 5.0)], RoadAttributes(name="B"))]
    with session_scope() as s:
        write_network(s, name, lines)
    ids = sorted(f["id"] for f in
                 client.get(f"/collections/{name}-segments/items").json()["features"])
    r = client.post(f"/collections/{name}-segments/merge", json={"segments": ids},
                    headers={**bearer("admin"), "If-Match": '"1", "1"'})
    assert r.status_code == 422 and set(r.json()["errors"]) == {"name"}


def test_every_write_needs_a_current_if_match(client, if_match_required) -> None:
    """PATCH, revert, split and merge: 428 without ``If-Match`` (``UGVMAP_IF_MATCH=required``),
    412 with a stale one, and nothing changes either way (revert and merge used to go through
    without it)."""
    name = f"ifm-{uuid.uuid4().hex[:8]}"
    with session_scope() as s:
        write_network(s, name, [RoadLine([(7.0, 5.0), (7.001, 5.0)]),
                                RoadLine([(7.001, 5.0), (7.002, 5.0)])])
    items = f"/collections/{name}-segments/items"
    a, b = sorted(f["id"] for f in client.get(items).json()["features"])
    admin = bearer("admin")
    r = client.patch(f"{items}/{a}", json={"name": "x"}, headers={**admin, "If-Match": '"1"'})
    assert r.status_code == 200  # a is now at version 2, b at 1
    writes = {
        "patch": lambda h: client.patch(f"{items}/{a}", json={"name": "y"}, headers=h),
        "revert": lambda h: client.post(f"{items}/{a}/revert", params={"to": 1}, headers=h),
        "split": lambda h: client.post(f"{items}/{a}/split", json={"fraction": 0.5},
                                       headers=h),
        "merge": lambda h: client.post(f"/collections/{name}-segments/merge",
                                       json={"segments": [a, b]}, headers=h),
    }
    stale = {"patch": '"1"', "revert": '"1"', "split": '"1"', "merge": '"2", "2"'}
    for action, write in writes.items():
        r = write(admin)
        assert (r.status_code, r.json()["code"]) == (428, "PreconditionRequired"), action
        r = write({**admin, "If-Match": stale[action]})
        assert (r.status_code, r.json()["code"]) == (412, "PreconditionFailed"), action
    r = writes["merge"]({**admin, "If-Match": '"2"'})  # one ETag for two segments
    assert r.status_code == 412
    versions = {f["id"]: f["properties"]["version"]
                for f in client.get(items).json()["features"]}
    assert versions == {a: 2, b: 1}
    assert len(client.get(f"{items}/{a}/history").json()["edits"]) == 1
    r = writes["revert"]({**admin, "If-Match": '"2"'})
    assert r.status_code == 200 and r.json()["properties"]["version"] == 3
    r = writes["merge"]({**admin, "If-Match": '"3", "1"'})
    assert r.status_code == 200, r.text


def test_validate_lists_pieces_and_dead_ends(database_url: str) -> None:
    """Two pieces: an L of two segments and a separate straight road; four dead ends."""
    name = f"pieces-{uuid.uuid4().hex[:6]}"
    lines = [RoadLine([(7.0, 5.0), (7.001, 5.0)]), RoadLine([(7.001, 5.0), (7.001, 5.002)]),
             RoadLine([(7.01, 5.0), (7.011, 5.0)])]
    with session_scope() as s:
        write_network(s, name, lines, node_crossings=False)
    code, out = _validate(name)
    assert code == 0, out
    assert "3 segments, 5 nodes, 4 dead ends, 2 connected components" in out
    assert "piece 1: 2 segments, 0.332 km, bbox 7.000000,5.000000,7.001000,5.002000" in out
    assert "piece 2: 1 segments, 0.111 km, bbox 7.010000,5.000000,7.011000,5.000000" in out
    assert "dead end: node" in out and "at 7.0010000,5.0020000" in out
    result = CliRunner().invoke(main, ["network", "validate", name, "--json"])
    report = json.loads(result.output)
    assert result.exit_code == 0 and report["ok"] and report["components"] == 2
    assert [p["segments"] for p in report["pieces"]] == [2, 1]
    assert sorted((d["lon"], d["lat"]) for d in report["dead_ends"]) == [
        (7.0, 5.0), (7.001, 5.002), (7.01, 5.0), (7.011, 5.0)]


def test_validate_json_of_a_broken_network_exits_1(database_url: str) -> None:
    net = grid_network()
    with session_scope() as s:
        s.execute(text("UPDATE road_nodes SET kind = 'endpoint' WHERE network_id = :n"),
                  {"n": net.network_id})
    result = CliRunner().invoke(main, ["network", "validate", net.network, "--json"])
    assert result.exit_code == 1
    report = json.loads(result.output)
    assert not report["ok"] and "node kind does not match its degree" in report["errors"]
