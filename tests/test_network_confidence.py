"""``confidence`` (how sure road extraction was of a segment, 0..1; null when not extracted) in
the API: items, the schemas clients type attributes by, the queryables, the vector tiles. It
is read-only: edits cannot set it, an attribute edit keeps it, split copies it and merge
weighs it by length. Values are set in the database as extraction writes them."""

from __future__ import annotations

import mapbox_vector_tile
import morecantile
import pytest
from sqlalchemy import text

from app.db.session import session_scope
from testkit.network_helpers import bearer, grid_network


@pytest.fixture()
def grid(database_url: str):
    """A grid network whose Row segments are 'extracted' (confidence 0.25 on Row 0, 0.9 on
    the others) and whose Column segments are not (null)."""
    net = grid_network()
    with session_scope() as s:
        s.execute(text("UPDATE road_segments SET confidence = CASE WHEN name = 'Row 0' "
                       "THEN 0.25 ELSE 0.9 END WHERE network_id = :n AND name LIKE 'Row %'"),
                  {"n": net.network_id})
    return net


def _features(client, network: str, **params) -> list[dict]:
    body = client.get(f"/collections/{network}-segments/items",
                      params={"limit": 100, **params}).json()
    return body["features"]


def test_items_schemas_and_queryables_type_confidence(client, grid) -> None:
    by_name: dict[str, set] = {}
    for f in _features(client, grid.network):
        by_name.setdefault(f["properties"]["name"], set()).add(f["properties"]["confidence"])
    assert by_name == {"Row 0": {0.25}, "Row 1": {0.9}, "Row 2": {0.9}, "Column 0": {None},
                       "Column 1": {None}, "Column 2": {None}}
    base = f"/collections/{grid.network}-segments"
    part5 = client.get(f"{base}/schema").json()["properties"]["confidence"]
    assert (part5["type"], part5["readOnly"]) == ("number", True)
    feature = client.get(f"{base}/feature-schema").json()
    assert feature["properties"]["properties"]["properties"]["confidence"]["type"] == "number"
    assert client.get(f"{base}/queryables").json()["properties"]["confidence"]["type"] == \
        "number"
    low = _features(client, grid.network, confidence="0.25")
    assert len(low) == 2 and {f["properties"]["name"] for f in low} == {"Row 0"}
    bad = client.get(f"{base}/items", params={"confidence": "low"})
    assert bad.status_code == 400 and "confidence must be a number" in bad.json()["message"]
    # The API document's item schema: a nullable number.
    item = client.get("/openapi.json").json()["components"]["schemas"]
    segment = next(v for k, v in item.items() if "confidence" in str(v.get("properties", {})
                                                                    .get("properties", {})))
    assert segment["properties"]["properties"]["properties"]["confidence"] == {
        "type": "number", "description": part5["description"], "nullable": True}


def test_tiles_carry_confidence(client, grid) -> None:
    tj = client.get(f"/networks/{grid.network}/tilejson.json").json()
    fields = next(layer["fields"] for layer in tj["vector_layers"] if layer["id"] == "segments")
    assert fields["confidence"] == "Number"
    t = morecantile.tms.get("WebMercatorQuad").tile(10.001, 50.001, 14)  # the whole grid
    tile = client.get(f"/networks/{grid.network}/tiles/{t.z}/{t.x}/{t.y}.mvt")
    features = mapbox_vector_tile.decode(tile.content)["segments"]["features"]
    by_name: dict[str, set] = {}
    for f in features:
        by_name.setdefault(f["properties"]["name"], set()).add(
            f["properties"].get("confidence"))
    assert by_name["Row 0"] == {0.25} and by_name["Column 1"] == {None}


def test_edits_cannot_set_it_and_keep_it(client, grid) -> None:
    items = f"/collections/{grid.network}-segments/items"
    row0 = next(f for f in _features(client, grid.network)
                if f["properties"]["name"] == "Row 0")
    url = f"{items}/{row0['id']}"
    editor = {**bearer("editor"), "If-Match": '"1"'}
    refused = client.patch(url, json={"confidence": 1.0, "speed_limit_kph": 30}, headers=editor)
    assert refused.status_code == 422 and set(refused.json()["errors"]) == {"confidence"}
    assert "read-only" in refused.json()["errors"]["confidence"]
    # A reviewer's attribute edit keeps the extraction's confidence; the history says who.
    r = client.patch(url, json={"speed_limit_kph": 30, "road_class": "residential"},
                     headers=editor)
    assert r.status_code == 200, r.text
    assert r.json()["properties"]["confidence"] == 0.25
    edits = client.get(f"{url}/history").json()["edits"]
    assert len(edits) == 1 and "confidence" not in edits[0]["new"]


def test_split_copies_and_merge_weighs_by_length(client, grid) -> None:
    items = f"/collections/{grid.network}-segments/items"
    row0 = sorted((f for f in _features(client, grid.network)
                   if f["properties"]["name"] == "Row 0"), key=lambda f: f["id"])
    admin = bearer("admin")
    split = client.post(f"{items}/{row0[0]['id']}/split", json={"fraction": 0.25},
                        headers={**admin, "If-Match": '"1"'})
    assert split.status_code == 200, split.text
    first, second = split.json()["features"]
    assert first["properties"]["confidence"] == second["properties"]["confidence"] == 0.25
    # Row 0's halves share a degree-2 node only after the split: the split's second part
    # and the original first (now 1/4) join at the new node.
    with session_scope() as s:
        s.execute(text("UPDATE road_segments SET confidence = 0.85 WHERE id = :id"),
                  {"id": second["id"]})
    merged = client.post(f"/collections/{grid.network}-segments/merge",
                         json={"segments": [first["id"], second["id"]]},
                         headers={**admin, "If-Match": '"2", "1"'})
    assert merged.status_code == 200, merged.text
    # A quarter at 0.25, three quarters at 0.85.
    assert merged.json()["properties"]["confidence"] == pytest.approx(0.7, abs=1e-6)
    history = client.get(f"{items}/{first['id']}/history").json()["edits"]
    assert history[-1]["action"] == "merge"
    assert history[-1]["old"]["confidence"] == 0.25
    assert history[-1]["new"]["confidence"] == pytest.approx(0.7, abs=1e-6)
