"""DELETE on a segment item: editor role and a current ``If-Match``, the topology stays valid
(orphaned nodes go, the others are re-kinded), the history keeps the whole segment, and
routing and tiles see the road gone.

The 3x3 grid of ``grid_network`` (12 segments, 9 nodes; 0.001 deg blocks at 50 N) has a
corner node at (10.0, 50.0) joining two segments: the first block of Row 0 (east) and the
first block of Column 0 (north).
"""

from __future__ import annotations

import threading
import time

import mapbox_vector_tile
import morecantile
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import session_scope
from app.network import collections as colls
from app.network.segment_deletion import delete_segment
from app.network.tokens import Principal
from cli.main import main
from testkit.network_helpers import bearer, grid_network

CORNER = (10.0, 50.0)


def _at(network_id: int, where: str) -> int:
    """The id of the network's segment matching an SQL condition on ``s``."""
    with session_scope() as s:
        return s.execute(text(f"SELECT id FROM road_segments s WHERE network_id = :n AND {where}"),
                         {"n": network_id}).scalar_one()


def _corner_segments(network_id: int) -> tuple[int, int]:
    """(first block of Row 0, first block of Column 0): the two segments at the corner."""
    start = "ST_Equals(ST_StartPoint(s.geom), ST_SetSRID(ST_MakePoint(10.0, 50.0), 4326))"
    return (_at(network_id, f"{start} AND name = 'Row 0'"),
            _at(network_id, f"{start} AND name = 'Column 0'"))


def _node_kinds(network_id: int) -> dict[tuple[float, float], str]:
    with session_scope() as s:
        rows = s.execute(text("SELECT round(ST_X(geom)::numeric, 4), "
                              "round(ST_Y(geom)::numeric, 4), kind FROM road_nodes "
                              "WHERE network_id = :n"), {"n": network_id}).all()
    return {(float(x), float(y)): kind for x, y, kind in rows}


def _validate(network: str) -> str:
    result = CliRunner().invoke(main, ["network", "validate", network])
    assert result.exit_code == 0, result.output
    return result.output


def test_delete_keeps_the_topology_and_the_history(client) -> None:
    net = grid_network()
    items = f"/collections/{net.network}-segments/items"
    row0, col0 = _corner_segments(net.network_id)
    before = client.get(f"{items}/{row0}").json()
    editor = bearer("editor")

    r = client.delete(f"{items}/{row0}", headers={**editor, "If-Match": '"1"'})
    assert r.status_code == 204 and r.content == b""
    assert client.get(f"{items}/{row0}").status_code == 404
    kinds = _node_kinds(net.network_id)
    # The corner keeps one segment (an endpoint now); the node east of it had 3 (now 2).
    assert kinds[CORNER] == "endpoint" and kinds[(10.001, 50.0)] == "node"
    assert "11 segments, 9 nodes, 1 dead ends" in _validate(net.network)

    edits = client.get(f"{items}/{row0}/history").json()["edits"]
    assert [(e["action"], e["version_from"], e["version_to"]) for e in edits] == \
        [("delete", 1, None)]
    assert edits[0]["edited_by"].startswith("editor-") and edits[0]["new"] is None
    old = edits[0]["old"]
    assert old["geometry"] == before["geometry"]
    assert {k: old[k] for k in before["properties"]} == before["properties"]

    # The corner's last segment: the corner node goes with it.
    assert client.delete(f"{items}/{col0}", headers={**editor, "If-Match": '"1"'}
                         ).status_code == 204
    assert CORNER not in _node_kinds(net.network_id)
    assert "10 segments, 8 nodes" in _validate(net.network)
    assert client.get(f"{items}/{col0}/history").json()["edits"][0]["action"] == "delete"
    # Gone is gone: a second DELETE finds nothing, and an id never used has no history.
    again = client.delete(f"{items}/{col0}", headers={**editor, "If-Match": '"1"'})
    assert again.status_code == 404 and again.json()["code"] == "NotFound"
    assert client.get(f"{items}/{2**62}/history").status_code == 404


def test_delete_needs_an_editor_and_the_current_version(client, if_match_required) -> None:
    net = grid_network()
    items = f"/collections/{net.network}-segments/items"
    fid, _ = _corner_segments(net.network_id)
    url = f"{items}/{fid}"
    cases = [({"If-Match": '"1"'}, 401, "Unauthorized"),
             ({**bearer("viewer"), "If-Match": '"1"'}, 403, "Forbidden"),
             (bearer("editor"), 428, "PreconditionRequired"),
             ({**bearer("editor"), "If-Match": '"2"'}, 412, "PreconditionFailed"),
             ({**bearer("editor"), "If-Match": "yes"}, 412, "PreconditionFailed")]
    for headers, status, code in cases:
        r = client.delete(url, headers=headers)
        assert (r.status_code, r.json()["code"]) == (status, code), r.text
    assert client.delete(url, headers={**bearer("editor"), "If-Match": '"2"'}
                         ).headers["etag"] == '"1"'
    # Deleting a node merges its two segments: admin only (403 for an editor), and a corner
    # between two differently named streets cannot merge (422); unknown collections and
    # items are not found.
    node = client.get(f"/collections/{net.network}-nodes/items").json()["features"][0]["id"]
    assert client.delete(f"/collections/{net.network}-nodes/items/{node}",
                         headers={**bearer("editor"), "If-Match": '"1"'}).status_code == 403
    assert client.delete(f"/collections/{net.network}-nodes/items/{node}",
                         headers={**bearer("admin"), "If-Match": '"1"'}).status_code == 422
    assert client.delete("/collections/nope-segments/items/1",
                         headers={**bearer("admin"), "If-Match": '"1"'}).status_code == 404
    assert client.delete(f"{items}/abc",
                         headers={**bearer("admin"), "If-Match": '"1"'}).status_code == 404
    # Nothing of that changed anything.
    assert client.get(url).json()["properties"]["version"] == 1
    assert client.get(items).json()["numberMatched"] == 12
    assert client.get(f"{url}/history").json()["edits"] == []
    assert "DELETE" in client.options(url).headers["allow"].split(", ")


def test_routes_and_tiles_see_the_road_gone(client) -> None:
    """A route along Row 0 takes the direct block; once it is deleted the route goes round
    by Column 0 / Row 1 / Column 1, and the vector tile no longer carries the segment."""
    net = grid_network()
    items = f"/collections/{net.network}-segments/items"
    row0, _ = _corner_segments(net.network_id)
    points = {"points": "10.0002,50.0;10.0008,50.0"}
    before = client.get(f"/networks/{net.network}/route", params=points).json()
    assert before["code"] == "Ok" and before["routes"][0]["distance"] < 50
    tile = morecantile.tms.get("WebMercatorQuad").tile(10.0005, 50.0, 16)
    tile_url = f"/networks/{net.network}/tiles/{tile.z}/{tile.x}/{tile.y}.mvt"

    def tile_ids() -> set[int]:
        layers = mapbox_vector_tile.decode(client.get(tile_url).content)
        return {f["id"] for f in layers["segments"]["features"]}

    assert row0 in tile_ids()
    assert client.delete(f"{items}/{row0}", headers={**bearer("editor"), "If-Match": '"1"'}
                         ).status_code == 204
    after = client.get(f"/networks/{net.network}/route", params=points).json()
    assert after["code"] == "Ok", after
    # Up Column 0 (111 m), along Row 1 (71.5 m), down Column 1 (111 m), back 14 m.
    assert 280 < after["routes"][0]["distance"] < 320
    assert row0 not in tile_ids()


def test_concurrent_deletes_at_one_node_leave_no_orphan(database_url: str) -> None:
    """The two segments at the corner deleted at once by two editors: the second waits until
    the first commits, then sees the node empty and deletes it (had each counted the other's
    segment still there, the corner would stay as a node of no road)."""
    net = grid_network()
    row0, col0 = _corner_segments(net.network_id)
    segments = colls.Collection(net.network, net.network_id, "segments")
    who = Principal("test", "editor")
    second_done = threading.Event()

    def second() -> None:
        with session_scope() as s:
            delete_segment(s, segments, col0, 1, who)
        second_done.set()

    with session_scope() as s:
        delete_segment(s, segments, row0, 1, who)
        other = threading.Thread(target=second)
        other.start()
        time.sleep(0.5)
        assert not second_done.is_set(), "the second delete did not wait for the first"
    other.join(timeout=30)
    assert second_done.is_set()
    assert CORNER not in _node_kinds(net.network_id)
    _validate(net.network)
