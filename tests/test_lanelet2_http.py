"""``GET /networks/{name}/lanelet2.osm``: the map over HTTP, loaded by the official lanelet2
library, with the area, origin and size rules and the project's error shape."""

from __future__ import annotations

import pytest

from app.lanelet2.export import PROJECTOR_FILE, projector_info
from app.lanelet2.router import lanelet2_settings
from app.settings import get_settings
from testkit.network_helpers import bearer, grid_network
from tests.lanelet2_support import load


def fetch_map(client, tmp_path, url: str, **kw):
    r = client.get(url, **kw)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith("application/xml")
    assert "lanelet2.osm" in r.headers["content-disposition"]
    lat, lon = (float(v) for v in r.headers["x-lanelet2-origin"].split(","))
    out = tmp_path / "lanelet2_map.osm"
    out.write_bytes(r.content)
    (tmp_path / PROJECTOR_FILE).write_text(projector_info((lat, lon)))
    return load(out)


def test_map_of_a_network_and_of_an_area(client, tmp_path) -> None:
    net = grid_network()
    m = fetch_map(client, tmp_path, f"/networks/{net.network}/lanelet2.osm")
    segments = {int(ll.attributes["segment_id"]) for ll in m.lanelets()
                if "direction" in ll.attributes}
    assert len(segments) == net.segments == 12
    # 2 + 2 lanes on every street of the grid.
    assert sum("direction" in ll.attributes for ll in m.lanelets()) == 12 * 4
    # A box around the middle of the first street: its one segment.
    area = client.get(f"/networks/{net.network}/lanelet2.osm",
                      params={"bbox": "10.0004,49.9999,10.0006,50.0001"})
    assert area.status_code == 200
    small = fetch_map(client, tmp_path, f"/networks/{net.network}/lanelet2.osm"
                      "?bbox=10.0004,49.9999,10.0006,50.0001&origin=50.0,10.0")
    assert len({ll.attributes["segment_id"] for ll in small.lanelets()}) == 1
    assert small.origin == (50.0, 10.0)


@pytest.mark.parametrize(("query", "status", "code"), [
    ("?bbox=1,2,3", 400, "InvalidParameterValue"),
    ("?bbox=10.1,50,10,50.1", 400, "InvalidParameterValue"),
    ("?bbox=-60,-60,-59,-59", 404, "NotFound"),
    ("?origin=95,10", 400, "InvalidParameterValue"),
    ("?origin=abc", 400, "InvalidParameterValue"),
])
def test_bad_requests(client, query: str, status: int, code: str) -> None:
    net = grid_network()
    r = client.get(f"/networks/{net.network}/lanelet2.osm{query}")
    assert (r.status_code, r.json()["code"]) == (status, code), r.text
    assert r.json()["message"]


def test_unknown_network_and_size_limit(client, monkeypatch) -> None:
    r = client.get("/networks/no-such-net/lanelet2.osm")
    assert (r.status_code, r.json()["code"]) == (404, "NotFound")
    net = grid_network()
    monkeypatch.setenv("UGVMAP_LANELET2_MAX_SEGMENTS", "5")
    lanelet2_settings.cache_clear()
    try:
        r = client.get(f"/networks/{net.network}/lanelet2.osm")
        assert (r.status_code, r.json()["code"]) == (422, "ResponseTooLarge")
        assert "12 segments" in r.json()["message"]
        assert client.get(f"/networks/{net.network}/lanelet2.osm",
                          params={"bbox": "10.0004,49.9999,10.0006,50.0001"}).status_code == 200
    finally:
        monkeypatch.delenv("UGVMAP_LANELET2_MAX_SEGMENTS")
        lanelet2_settings.cache_clear()


def test_read_role_applies(client, monkeypatch, tmp_path) -> None:
    net = grid_network()
    monkeypatch.setenv("UGVMAP_NETWORK_READ_ROLE", "viewer")
    get_settings.cache_clear()
    try:
        url = f"/networks/{net.network}/lanelet2.osm"
        assert client.get(url).status_code == 401
        fetch_map(client, tmp_path, url, headers=bearer("viewer"))
    finally:
        monkeypatch.delenv("UGVMAP_NETWORK_READ_ROLE")
        get_settings.cache_clear()
