"""OGC API Features Part 4 on the road network: what POST, PUT, PATCH, DELETE and OPTIONS do
to segments and nodes, that bad input is a clear 4xx changing nothing, and that the topology
``ugvmap network validate`` checks stays valid. (QGIS's own request sequence:
``tests/test_qgis_editing.py``.)

The 3x3 grid of ``grid_network``: streets every 0.001 deg around 10 E 50 N, 12 segments at 9
nodes, every segment 2+2 lanes at 50 km/h.
"""

from __future__ import annotations

import pytest
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from testkit.network_helpers import bearer, grid_network


def _validate(network: str) -> str:
    result = CliRunner().invoke(main, ["network", "validate", network])
    assert result.exit_code == 0, result.output
    return result.output


def _line(*coords: tuple[float, float]) -> dict:
    return {"type": "Feature", "geometry": {"type": "LineString",
                                            "coordinates": [list(c) for c in coords]},
            "properties": {"name": "Created", "road_class": "service"}}


def _counts(network_id: int) -> tuple[int, int, int]:
    with session_scope() as s:
        return s.execute(text(
            "SELECT (SELECT count(*) FROM road_segments WHERE network_id = :n), "
            "(SELECT count(*) FROM road_nodes WHERE network_id = :n), "
            "(SELECT count(*) FROM segment_edits WHERE network_id = :n)"),
            {"n": network_id}).one()


@pytest.fixture()
def grid(client):
    net = grid_network()
    return net, f"/collections/{net.network}-segments/items"


def test_post_creates_a_segment_joined_at_existing_nodes(client, grid) -> None:
    """Both ends within 0.5 m of nodes: the road joins them exactly (a diagonal across the
    first block), is not noded where it crosses nothing, and answers 201 + Location."""
    net, items = grid
    body = _line((10.000002, 50.000001), (10.001, 50.001))
    r = client.post(items, json=body, headers=bearer("editor"))
    assert r.status_code == 201, r.text
    created = r.json()
    assert r.headers["location"].endswith(f"{items}/{created['id']}")
    assert r.headers["location"].startswith("http")
    assert r.headers["etag"] == '"1"' and r.headers["content-type"] == "application/geo+json"
    assert created["geometry"]["coordinates"] == [[10.0, 50.0], [10.001, 50.001]]
    assert created["properties"]["length_m"] > 100
    assert "13 segments, 9 nodes" in _validate(net.network)
    assert client.get(r.headers["location"]).json()["properties"]["name"] == "Created"


@pytest.mark.parametrize(("body", "field", "words"), [
    ({"type": "Feature", "properties": {}}, "geometry", "required"),
    ({"type": "Feature", "geometry": {"type": "Point", "coordinates": [10, 50]}},
     "geometry", "LineString"),
    (_line((10.0, 50.0), (10.0, 50.0)), "geometry", "long"),
    (_line((10.0, 50.0), (10.0000001, 50.0000002), (10.0, 50.000001)), "geometry",
     "two different nodes"),
    (_line((10.0, 50.0), (10.001, 50.0)), "geometry", "duplicates segment"),
    (_line((10.0, 50.0), (200.0, 50.0)), "geometry", "lon -180..180"),
    ({**_line((10.0, 50.0), (10.0005, 49.999)), "properties": {"colour": "red"}},
     "colour", "not a segment attribute"),
    ({**_line((10.0, 50.0), (10.0005, 49.999)), "properties": {"lanes_forward": 0,
                                                              "lanes_backward": 0}},
     "lanes_forward", "at least one lane"),
    ({**_line((10.0, 50.0), (10.0005, 49.999)), "type": "FeatureCollection"}, "type",
     "Feature"),
    ({**_line((10.0, 50.0), (10.0005, 49.999)), "extra": 1}, "extra", "not a feature member"),
])
def test_post_refuses_what_would_break_a_rule_and_changes_nothing(client, grid, body, field,
                                                                   words) -> None:
    net, items = grid
    before = _counts(net.network_id)
    r = client.post(items, json=body, headers=bearer("editor"))
    assert (r.status_code, r.json()["code"]) == (422, "InvalidValue"), r.text
    assert words in r.json()["errors"][field]
    assert _counts(net.network_id) == before


def test_post_needs_an_editor_a_json_body_and_a_known_collection(client, grid) -> None:
    net, items = grid
    body = _line((10.0, 50.0), (10.0005, 49.999))
    assert client.post(items, json=body).status_code == 401
    assert client.post(items, json=body, headers=bearer("viewer")).status_code == 403
    r = client.post(items, content="{", headers={**bearer("editor"),
                                                 "Content-Type": "application/geo+json"})
    assert (r.status_code, r.json()["code"]) == (400, "InvalidParameterValue")
    r = client.post(items, content="x", headers={**bearer("editor"),
                                                 "Content-Type": "text/plain"})
    assert r.status_code == 415
    r = client.post("/collections/nope-segments/items", json=body, headers=bearer("editor"))
    assert r.status_code == 404
    assert _counts(net.network_id)[0] == 12


def test_put_replaces_the_whole_feature_but_keeps_its_nodes(client, grid) -> None:
    net, items = grid
    fid = client.get(items).json()["features"][0]["id"]
    feature = client.get(f"{items}/{fid}").json()
    coords = feature["geometry"]["coordinates"]
    mid = [(coords[0][0] + coords[-1][0]) / 2 + 0.0001, (coords[0][1] + coords[-1][1]) / 2]
    # Everything a client holds comes back, server-kept properties with stale values too.
    sent = {**feature, "properties": {**feature["properties"], "version": 77,
                                      "length_m": 1.0, "speed_limit_kph": 20,
                                      "name": None, "attrs": {"k": "v"}},
            "geometry": {"type": "LineString", "coordinates": [coords[0], mid, coords[-1]]}}
    sent["properties"].pop("lanes_backward")
    r = client.put(f"{items}/{fid}", json=sent, headers={**bearer("editor"), "If-Match": '"1"'})
    assert r.status_code == 200, r.text
    props = r.json()["properties"]
    assert (props["version"], props["speed_limit_kph"], props["name"]) == (2, 20, None)
    assert props["lanes_backward"] == 1 and props["attrs"] == {"k": "v"}  # the default
    assert props["length_m"] > feature["properties"]["length_m"]
    edits = client.get(f"{items}/{fid}/history").json()["edits"]
    assert [e["action"] for e in edits] == ["replace"]
    moved = {**sent, "geometry": {"type": "LineString",
                                  "coordinates": [[10.5, 50.0], coords[-1]]}}
    r = client.put(f"{items}/{fid}", json=moved, headers=bearer("editor"))
    assert r.status_code == 422 and "nodes" in r.json()["errors"]["geometry"]
    # No creation by PUT: an unknown id is a 404.
    assert client.put(f"{items}/{2**40}", json=sent, headers=bearer("editor")).status_code == 404
    _validate(net.network)


def test_moving_a_node_drags_its_segments_and_keeps_the_topology(client, grid) -> None:
    net, _ = grid
    nodes = f"/collections/{net.network}-nodes/items"
    centre = next(f for f in client.get(nodes).json()["features"]
                  if f["geometry"]["coordinates"] == [10.001, 50.001])
    url = f"{nodes}/{centre['id']}"
    assert centre["properties"]["degree"] == 4
    r = client.patch(url, json={"geometry": {"type": "Point", "coordinates": [10.0012, 50.0011]}},
                     headers={**bearer("editor"), "If-Match": '"1"'})
    assert r.status_code == 200, r.text
    assert r.json()["properties"]["version"] == 2 and r.headers["etag"] == '"2"'
    segments = f"/collections/{net.network}-segments/items"
    touching = [f for f in client.get(segments, params={"limit": 100}).json()["features"]
                if centre["id"] in (f["properties"]["source_node"],
                                    f["properties"]["target_node"])]
    assert len(touching) == 4
    for f in touching:
        ends = [f["geometry"]["coordinates"][0], f["geometry"]["coordinates"][-1]]
        assert [10.0012, 50.0011] in ends and f["properties"]["version"] == 2
        history = client.get(f"{segments}/{f['id']}/history").json()["edits"]
        assert history[-1]["action"] == "move-node"
        # A move is topology: the segment cannot be reverted away from its node.
        assert client.post(f"{segments}/{f['id']}/revert", params={"to": 1},
                           headers=bearer("editor")).status_code == 422
    _validate(net.network)
    # Onto another node: refused (nodes are not merged), nothing moves.
    r = client.patch(url, json={"geometry": {"type": "Point", "coordinates": [10.0, 50.0]}},
                     headers=bearer("editor"))
    assert r.status_code == 422 and "already there" in r.json()["errors"]["geometry"]
    assert client.get(url).json()["geometry"]["coordinates"] == [10.0012, 50.0011]
    # Attributes of its own; kind and degree follow the segments.
    r = client.patch(url, json={"kind": "endpoint"}, headers=bearer("editor"))
    assert r.status_code == 422 and "read-only" in r.json()["errors"]["kind"]
    edits = client.get(f"{url}/history").json()["edits"]
    assert [(e["action"], e["conditional"]) for e in edits] == [("move", True)]


def test_deleting_a_node_merges_its_two_segments(client) -> None:
    from ingest.network import RoadAttributes, RoadLine, write_network

    with session_scope() as s:
        net = write_network(s, "part4-merge", [
            RoadLine([(8.0, 47.0), (8.001, 47.0)], RoadAttributes(1, 1, 30.0, name="A")),
            RoadLine([(8.001, 47.0), (8.002, 47.0)], RoadAttributes(1, 1, 30.0, name="A"))])
    nodes = "/collections/part4-merge-nodes/items"
    middle = next(f for f in client.get(nodes).json()["features"]
                  if f["properties"]["degree"] == 2)
    r = client.delete(f"{nodes}/{middle['id']}", headers=bearer("admin"))
    assert r.status_code == 204
    assert "1 segments, 2 nodes" in _validate(net.network)
    edits = client.get(f"{nodes}/{middle['id']}/history").json()["edits"]
    assert [(e["action"], e["conditional"]) for e in edits] == [("delete", False)]
    end = next(f for f in client.get(nodes).json()["features"])
    r = client.delete(f"{nodes}/{end['id']}", headers=bearer("admin"))
    assert r.status_code == 422 and "endpoint goes with its segment" in r.json()["message"]


def test_options_says_what_each_resource_answers(client, grid) -> None:
    net, items = grid
    cases = {items: "GET, HEAD, OPTIONS, POST",
             f"{items}/1": "DELETE, GET, HEAD, OPTIONS, PATCH, PUT",
             f"{items}/unknown_id": "DELETE, GET, HEAD, OPTIONS, PATCH, PUT",
             f"/collections/{net.network}-nodes/items": "GET, HEAD, OPTIONS, POST",
             "/conformance": "GET, HEAD, OPTIONS", "/jobs": "GET, HEAD, OPTIONS, POST"}
    for url, allow in cases.items():
        r = client.options(url)
        assert (r.status_code, r.headers["allow"], r.content) == (200, allow, b""), url
    for url in ("/collections/nope-segments/items", "/collections/nope-segments/items/1",
                "/no/such/path"):
        r = client.options(url)
        assert (r.status_code, r.json()["code"]) == (404, "NotFound"), url
    conformance = client.get("/conformance").json()["conformsTo"]
    part4 = "http://www.opengis.net/spec/ogcapi-features-4/1.0/conf/"
    assert {part4 + "create-replace-delete", part4 + "update"} <= set(conformance)


def test_concurrent_roads_ending_at_one_new_spot_share_its_node(live_server: str) -> None:
    """Two editors draw roads from different junctions to the same new dead end at once:
    node placement is serialised per network, so the second joins the node the first
    created (validate finds no two nodes at one location)."""
    import threading

    import httpx

    net = grid_network()
    items = f"{live_server}/collections/{net.network}-segments/items"
    spot = (10.0015, 49.999)
    bodies = [_line((10.001, 50.0), spot), _line((10.002, 50.0), spot)]
    results: list[int] = []
    barrier = threading.Barrier(len(bodies))

    def post(body: dict) -> None:
        barrier.wait()
        results.append(httpx.post(items, json=body, headers=bearer("editor"),
                                  timeout=30).status_code)

    threads = [threading.Thread(target=post, args=(b,)) for b in bodies]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert results == [201, 201]
    out = _validate(net.network)
    assert "14 segments, 10 nodes" in out and "topology OK" in out
