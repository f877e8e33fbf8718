"""OGC API Features Part 2 (CRS by reference): items and single features in EPSG:3857,
EPSG:4326 (latitude first) and the network's UTM zone, boxes given in them, and edits sent
in them (``Content-Crs``), reprojected by PostGIS; round trips come back where they were.
Expected coordinates come from pyproj, not from the server."""

from __future__ import annotations

import httpx
import pytest
from pyproj import Transformer

from testkit.network_helpers import bearer, grid_network, token
from tests.qgis_oapif import QgisLayer

EPSG = "http://www.opengis.net/def/crs/EPSG/0/"
CRS84 = "http://www.opengis.net/def/crs/OGC/1.3/CRS84"
UTM = 32632  # 10 E 50 N


def _to(epsg: int):
    return Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True).transform


@pytest.fixture()
def grid(client):
    net = grid_network()
    return net, f"/collections/{net.network}-segments/items"


def test_collections_list_their_crs_and_conformance_says_part_2(client, grid) -> None:
    net, _ = grid
    doc = client.get(f"/collections/{net.network}-segments").json()
    assert doc["crs"] == [CRS84, f"{EPSG}4326", f"{EPSG}3857", f"{EPSG}{UTM}"]
    assert doc["storageCrs"] == CRS84
    assert "http://www.opengis.net/spec/ogcapi-features-2/1.0/conf/crs" in \
        client.get("/conformance").json()["conformsTo"]


@pytest.mark.parametrize("epsg", [3857, UTM])
def test_items_in_a_metric_crs(client, grid, epsg: int) -> None:
    _, items = grid
    lonlat = client.get(items, params={"limit": 100}).json()["features"]
    r = client.get(items, params={"limit": 100, "crs": f"{EPSG}{epsg}"})
    assert r.status_code == 200 and r.headers["content-crs"] == f"<{EPSG}{epsg}>"
    to = _to(epsg)
    for a, b in zip(lonlat, r.json()["features"], strict=True):
        for (lon, lat), (x, y) in zip(a["geometry"]["coordinates"],
                                      b["geometry"]["coordinates"], strict=True):
            ex, ey = to(lon, lat)
            assert abs(x - ex) < 1e-5 and abs(y - ey) < 1e-5
    one = client.get(f"{items}/{lonlat[0]['id']}", params={"crs": f"{EPSG}{epsg}"})
    assert one.json()["geometry"] == r.json()["features"][0]["geometry"]
    assert one.headers["content-crs"] == f"<{EPSG}{epsg}>"


def test_epsg_4326_is_latitude_first(client, grid) -> None:
    _, items = grid
    first = client.get(items).json()["features"][0]
    r = client.get(f"{items}/{first['id']}", params={"crs": f"{EPSG}4326"})
    assert r.json()["geometry"]["coordinates"] == \
        [[lat, lon] for lon, lat in first["geometry"]["coordinates"]]


@pytest.mark.parametrize("epsg", [3857, UTM, 4326])
def test_bbox_in_another_crs_selects_what_the_lonlat_box_does(client, grid, epsg: int) -> None:
    """The first block of Row 0 and Column 0 (the box around its south-west corner)."""
    _, items = grid
    box = (9.99995, 49.99995, 10.00005, 50.00005)
    expected = {f["id"] for f in client.get(items, params={
        "bbox": ",".join(map(str, box))}).json()["features"]}
    assert len(expected) == 2
    if epsg == 4326:
        corners = [box[1], box[0], box[3], box[2]]
    else:
        to = _to(epsg)
        corners = [*to(box[0], box[1]), *to(box[2], box[3])]
    r = client.get(items, params={"bbox": ",".join(map(str, corners)),
                                  "bbox-crs": f"{EPSG}{epsg}"})
    assert r.status_code == 200, r.text
    assert {f["id"] for f in r.json()["features"]} == expected


@pytest.mark.parametrize(("params", "words"), [
    ({"crs": f"{EPSG}2056"}, "not offered"), ({"crs": "EPSG:3857"}, "not offered"),
    ({"bbox-crs": f"{EPSG}9999"}, "not offered"),
    ({"bbox": "0,0,1e9,1", "bbox-crs": f"{EPSG}3857"}, "extent"),
    ({"bbox": "5,5,1,1", "bbox-crs": f"{EPSG}3857"}, "must not exceed"),
])
def test_crs_parameters_that_are_not_offered_are_400(client, grid, params, words) -> None:
    _, items = grid
    r = client.get(items, params=params)
    assert (r.status_code, r.json()["code"]) == (400, "InvalidParameterValue")
    assert words in r.json()["message"]


def test_qgis_digitises_in_web_mercator(live_server: str) -> None:
    """QGIS with the layer in EPSG:3857 (Part 2 declared, the user picks it): items requested
    with ``bbox``, ``bbox-crs`` and ``crs`` (``qgsoapiffeaturedownloaderimpl.cpp`` appends
    ``&bbox-crs=`` and ``&crs=`` with the bare OGC URI), the new road posted and its line
    patched in metres with ``Content-Crs: <bare URI>``
    (``qgsoapifcreatefeaturerequest.cpp``, ``qgsoapifpatchfeaturerequest.cpp``)."""
    net = grid_network()
    to = _to(3857)
    with httpx.Client(base_url=live_server, timeout=30) as http:
        layer = QgisLayer(http, f"/collections/{net.network}-segments/items", "u",
                          token("editor"), crs=f"{EPSG}3857")
        layer.load()
        x0, y0 = to(9.999, 49.999)
        x1, y1 = to(10.003, 50.003)
        r = layer.send("GET", f"{layer.items}?limit=1000&bbox={x0},{y0},{x1},{y1}"
                              f"&bbox-crs={EPSG}3857&crs={EPSG}3857")
        assert r.json()["numberMatched"] == 12 and r.headers["content-crs"] == f"<{EPSG}3857>"
        start, end = to(10.0005, 50.0), to(10.0005, 49.9995)
        fid = layer.add_feature({"type": "LineString", "coordinates": [start, end]}, {})
        assert fid is not None, layer.log
        created = http.get(f"{layer.items}/{fid}").json()
        assert created["geometry"]["coordinates"][0] == [10.0005, 50.0]
        lon, lat = created["geometry"]["coordinates"][-1]
        assert abs(lon - 10.0005) < 1e-9 and abs(lat - 49.9995) < 1e-9
        # The line as QGIS holds it (fetched in 3857), bent in the middle, patched back.
        held = http.get(f"{layer.items}/{fid}", params={"crs": f"{EPSG}3857"}).json()
        a, b = held["geometry"]["coordinates"]
        bent = [a, [(a[0] + b[0]) / 2 + 5, (a[1] + b[1]) / 2], b]
        assert layer.change_geometry(fid, {"type": "LineString", "coordinates": bent})
        line = http.get(f"{layer.items}/{fid}").json()["geometry"]["coordinates"]
        assert line[0] == [10.0005, 50.0] and len(line) == 3


def test_round_trip_in_utm_and_lat_first_changes_nothing(client, grid) -> None:
    """GET in a CRS, PUT the same geometry back in it: the stored line is unchanged (to
    1e-9 deg) and stays on its nodes."""
    _, items = grid
    fid = client.get(items).json()["features"][0]["id"]
    before = client.get(f"{items}/{fid}").json()
    for crs in (f"{EPSG}{UTM}", f"{EPSG}4326"):
        held = client.get(f"{items}/{fid}", params={"crs": crs}).json()
        version = held["properties"]["version"]
        r = client.put(f"{items}/{fid}", json=held,
                       headers={**bearer("editor"), "If-Match": f'"{version}"',
                                "Content-Crs": f"<{crs}>"})
        assert r.status_code == 200, r.text
        for (x, y), (u, v) in zip(r.json()["geometry"]["coordinates"],
                                  before["geometry"]["coordinates"], strict=True):
            assert abs(x - u) < 1e-9 and abs(y - v) < 1e-9
    r = client.patch(f"{items}/{fid}", json={"geometry": before["geometry"]},
                     headers={**bearer("editor"), "Content-Crs": f"{EPSG}2056"})
    assert (r.status_code, r.json()["code"]) == (400, "InvalidParameterValue")
