"""Editing from QGIS 3.34 LTR through OGC API Features Part 4, its requests replayed against
a real ``ugvmap serve`` (uvicorn over a socket, so header names are read as QGIS reads them)
on a real PostGIS. What QGIS sends and reads is documented, with the source files it comes
from, in :mod:`tests.qgis_oapif`.

The grid of ``grid_network`` (3x3 streets, 0.001 deg blocks at 10 E 50 N): the new road
leaves Row 0 in the middle of its first block (a T junction) and ends in a new dead end.
"""

from __future__ import annotations

import json

import httpx
import pytest
from click.testing import CliRunner

from cli.main import main
from testkit.network_helpers import grid_network, token
from tests.qgis_oapif import QgisLayer, ogr_fields

EVERYTHING = {"AddFeatures", "ChangeAttributeValues", "ChangeGeometries", "DeleteFeatures",
              "SupportsPatch"}
T_START = [10.0005, 50.0]  # the middle of Row 0's first block
ROAD = {"type": "LineString", "coordinates": [T_START, [10.0005, 49.9995]]}


def _validate(network: str) -> str:
    result = CliRunner().invoke(main, ["network", "validate", network])
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture()
def http(live_server: str):
    with httpx.Client(base_url=live_server, timeout=30) as c:
        yield c


def test_qgis_adds_edits_and_deletes_a_road(http: httpx.Client) -> None:
    """QGIS's whole editing session on a segments layer: capabilities from OPTIONS, a road
    digitised with two fields filled in, an attribute edit (one value set to NULL), a
    geometry edit and a deletion, none with If-Match, credentials as HTTP Basic with the
    token as password; the topology stays valid at every step."""
    net = grid_network()
    layer = QgisLayer(http, f"/collections/{net.network}-segments/items", "qgis-user",
                      token("editor", "map-team"))
    layer.load()
    # The id is invisible to QGIS (OGR makes it the feature id); segment_id carries it.
    assert "segment_id" in layer.fields and "id" not in layer.fields
    assert layer.capabilities() == EVERYTHING

    fid = layer.add_feature(ROAD, {"name": "New Lane", "road_class": "residential",
                                   "lanes_forward": 1})
    assert fid is not None, layer.log
    created = http.get(f"{layer.items}/{fid}").json()
    props = created["properties"]
    assert (props["name"], props["road_class"], props["lanes_backward"], props["oneway"]) == \
        ("New Lane", "residential", 1, "none")  # empty fields took the defaults
    assert props["segment_id"] == int(fid) and props["updated_by"] == "map-team"
    assert created["geometry"]["coordinates"][0] == T_START
    nodes = f"/collections/{net.network}-nodes/items"
    junction = http.get(f"{nodes}/{props['source_node']}").json()["properties"]
    end = http.get(f"{nodes}/{props['target_node']}").json()["properties"]
    assert (junction["kind"], junction["degree"], end["kind"]) == ("junction", 3, "endpoint")
    assert "14 segments, 11 nodes" in _validate(net.network)

    assert layer.change_attributes(fid, {"speed_limit_kph": 30, "name": None})
    bent = {"type": "LineString",
            "coordinates": [T_START, [10.0006, 49.99975], [10.0005, 49.9995]]}
    assert layer.change_geometry(fid, bent)
    props = http.get(f"{layer.items}/{fid}").json()["properties"]
    assert (props["speed_limit_kph"], props["name"], props["version"]) == (30, None, 3)
    _validate(net.network)

    assert layer.delete(fid)
    assert http.get(f"{layer.items}/{fid}").status_code == 404
    assert http.get(f"{nodes}/{end['node_id']}").status_code == 404  # no dangling node
    assert http.get(f"{nodes}/{junction['node_id']}").json()["properties"]["kind"] == "node"
    assert "13 segments, 10 nodes" in _validate(net.network)

    edits = http.get(f"{layer.items}/{fid}/history").json()["edits"]
    assert [(e["action"], e["version_from"], e["version_to"], e["conditional"])
            for e in edits] == [("create", None, 1, True), ("update", 1, 2, False),
                                ("update", 2, 3, False), ("delete", 3, None, False)]
    assert all(status < 300 for _, _, status in layer.log), layer.log


def test_qgis_copies_a_road_with_every_column_it_read(http: httpx.Client) -> None:
    """Copy and paste in QGIS sends a feature with every column as OGR read it: the server's
    own (segment_id, version, length_m, updated_at...) are ignored, ``attrs`` arrives as JSON
    text and is stored as the object it was."""
    net = grid_network()
    layer = QgisLayer(http, f"/collections/{net.network}-segments/items", "u",
                      token("editor"))
    layer.load()
    http.patch(f"{layer.items}/{layer.first_page['features'][0]['id']}",
               json={"attrs": {"lit": "yes"}}, headers={"Authorization": layer._auth()[
                   "Authorization"]}).raise_for_status()
    layer.load()
    names, _, rows = ogr_fields(json.dumps(layer.first_page).encode())
    copied = dict(zip(names, rows[0], strict=True))
    assert copied["attrs"] == '{ "lit": "yes" }'  # OGR's JSON text of the object
    copied = {k: v.isoformat() if hasattr(v, "isoformat") else v for k, v in copied.items()}
    fid = layer.add_feature(ROAD, copied)
    assert fid is not None, layer.log
    props = http.get(f"{layer.items}/{fid}").json()["properties"]
    assert props["attrs"] == {"lit": "yes"} and props["name"] == copied["name"]
    assert (props["segment_id"], props["version"]) == (int(fid), 1)
    assert props["segment_id"] != copied["segment_id"]
    _validate(net.network)


def test_qgis_sets_a_traffic_light_on_a_node(http: httpx.Client) -> None:
    """A nodes layer is editable the same way: an editor's attribute edit (a traffic light)
    goes through; adding a node (which splits a road) is an admin's, so QGIS with an editor
    token reports the creation failed and nothing changes."""
    net = grid_network()
    nodes = f"/collections/{net.network}-nodes/items"
    layer = QgisLayer(http, nodes, "u", token("editor"))
    layer.load()
    assert layer.capabilities() == EVERYTHING
    node = str(layer.first_page["features"][0]["id"])
    assert layer.change_attributes(node, {"traffic_light": True})
    assert http.get(f"{nodes}/{node}").json()["properties"]["traffic_light"] is True
    tiles = http.get(f"/networks/{net.network}/tilejson.json").json()
    assert tiles["vector_layers"][1]["fields"]["traffic_light"] == "Boolean"
    point = {"type": "Point", "coordinates": [10.0005, 50.001]}
    assert layer.add_feature(point, {}) is None
    assert layer.log[-1][2] == 403
    admin = QgisLayer(http, nodes, "u", token("admin"))
    admin.load()
    created = admin.add_feature(point, {"traffic_light": True})
    assert created is not None
    props = http.get(f"{nodes}/{created}").json()["properties"]
    assert (props["kind"], props["degree"], props["traffic_light"]) == ("node", 2, True)
    assert "13 segments, 10 nodes" in _validate(net.network)


def test_allow_and_location_leave_the_server_as_qgis_spells_them(http: httpx.Client) -> None:
    """QGIS 3.34 finds ``Allow`` and ``Location`` only in exactly that case; uvicorn's default
    (httptools) writes every header name lower-cased, so ``ugvmap serve`` runs h11 and the app
    spells names conventionally. Checked on the raw bytes of the socket."""
    net = grid_network()
    raw = httpx.Request("OPTIONS", f"{http.base_url}/collections/{net.network}-segments/items")
    with httpx.Client() as plain:
        response = plain.send(raw)
    names = [k for k, _ in response.headers.raw]
    assert b"Allow" in names and b"allow" not in names
    assert b"Content-Length" in names
    assert response.headers["allow"] == "GET, HEAD, OPTIONS, POST"
