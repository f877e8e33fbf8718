"""OGC API - Features: paging, bbox, single items, errors, and GDAL's OAPIF driver reading it."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from testkit.network_helpers import grid_network


@pytest.fixture(scope="module")
def grid(database_url: str):
    return grid_network()


def test_conformance_and_collections(client, grid) -> None:
    conf = client.get("/conformance").json()["conformsTo"]
    assert any(c.endswith("/conf/core") for c in conf) and any(c.endswith("/geojson")
                                                               for c in conf)
    ids = {c["id"] for c in client.get("/collections").json()["collections"]}
    assert {f"{grid.network}-segments", f"{grid.network}-nodes"} <= ids
    meta = client.get(f"/collections/{grid.network}-segments").json()
    assert meta["extent"]["spatial"]["bbox"][0] == pytest.approx([10.0, 50.0, 10.002, 50.002])


def test_paging_visits_every_feature_once(client, grid) -> None:
    url = f"/collections/{grid.network}-segments/items?limit=5"
    seen, pages = [], 0
    while url:
        page = client.get(url)
        assert page.headers["content-type"].startswith("application/geo+json")
        body = page.json()
        assert body["numberMatched"] == 12 and body["numberReturned"] == len(body["features"])
        seen += [f["id"] for f in body["features"]]
        nxt = [link["href"] for link in body["links"] if link["rel"] == "next"]
        url, pages = (nxt[0] if nxt else None), pages + 1
    assert pages == 3 and len(seen) == len(set(seen)) == grid.segments == 12


def test_bbox_and_nodes(client, grid) -> None:
    # The left column plus the stubs of the rows that start on it: 2 + 3 segments.
    box = "9.9999,49.9999,10.0001,50.0021"
    body = client.get(f"/collections/{grid.network}-segments/items",
                      params={"bbox": box, "limit": 100}).json()
    assert body["numberMatched"] == 5
    nodes = client.get(f"/collections/{grid.network}-nodes/items", params={"limit": 100}).json()
    degrees = sorted(f["properties"]["degree"] for f in nodes["features"])
    assert degrees == [2, 2, 2, 2, 3, 3, 3, 3, 4]
    kinds = {f["properties"]["kind"] for f in nodes["features"] if f["properties"]["degree"] == 4}
    assert kinds == {"junction"}


@pytest.mark.parametrize(("query", "status"), [
    ("bbox=1,2,3", 400), ("bbox=a,b,c,d", 400), ("bbox=0,3,1,1", 400), ("limit=0", 400),
    ("limit=x", 400), ("limit=--5", 400), ("offset=-1", 400), ("colour=red", 400),
    ("bbox=nan,0,1,1", 400), ("bbox=1,2,3,4,5", 400), ("limit=999999999", 200),
    ("offset=99999999999999999999999", 400), ("bbox-crs=EPSG:4326", 400), ("f=html", 400),
    ("datetime=yesterday", 400), ("datetime=2020-01-02/2020-01-01", 400),
    ("datetime=2020-01-01/2020-01-02/2020-01-03", 400), ("lanes_forward=two", 400),
    ("is_junction=yes", 400), ("speed_limit_kph=nan", 400), ("name=a%00b", 400),
    ("kind=junction", 400), ("crs=EPSG:4326", 400),
    ("crs=http://www.opengis.net/def/crs/OGC/1.3/CRS84", 200)])
def test_bad_parameters(client, grid, query: str, status: int) -> None:
    r = client.get(f"/collections/{grid.network}-segments/items?{query}")
    assert r.status_code == status, r.text
    if status == 400:
        assert r.json()["code"] == "InvalidParameterValue"


def test_unknown_collection_and_item(client, grid) -> None:
    assert client.get("/collections/nope-segments").status_code == 404
    assert client.get(f"/collections/{grid.network}-edges/items").status_code == 404
    for fid in ("0", "abc", "99999999999999999999999", "-1"):
        r = client.get(f"/collections/{grid.network}-segments/items/{fid}")
        assert r.status_code == 404 and r.json()["code"] == "NotFound"


@pytest.mark.slow
def test_gdal_oapif_driver_reads_the_network(live_server: str, grid, tmp_path: Path) -> None:
    out = tmp_path / "segments.geojson"
    subprocess.run(["ogr2ogr", "-f", "GeoJSON", str(out), f"OAPIF:{live_server}",
                    f"{grid.network}-segments"], check=True, capture_output=True, timeout=60)
    features = json.loads(out.read_text())["features"]
    assert len(features) == 12
    names = sorted({f["properties"]["name"] for f in features})
    assert names == [f"Column {i}" for i in range(3)] + [f"Row {i}" for i in range(3)]
    assert {f["properties"]["lanes_forward"] for f in features} == {2}
    info = subprocess.run(["ogrinfo", "-ro", "-so", f"OAPIF:{live_server}",
                           f"{grid.network}-nodes"], check=True, capture_output=True,
                          text=True, timeout=60).stdout
    assert "Feature Count: 9" in info


def test_reads_can_require_a_token(client, grid, monkeypatch: pytest.MonkeyPatch) -> None:
    from app.settings import get_settings
    from testkit.network_helpers import bearer

    items = f"/collections/{grid.network}-segments/items"
    tile = f"/networks/{grid.network}/tiles/14/8647/5556.mvt"
    monkeypatch.setenv("UGVMAP_NETWORK_READ_ROLE", "editor")
    get_settings.cache_clear()
    try:
        assert client.get(items).status_code == 401
        assert client.get(tile).status_code == 401
        assert client.get(items, headers=bearer("viewer")).status_code == 403
        assert client.get(items, headers=bearer("editor")).status_code == 200
        assert client.get(tile, headers=bearer("admin")).status_code == 200
    finally:
        monkeypatch.delenv("UGVMAP_NETWORK_READ_ROLE")
        get_settings.cache_clear()
    assert client.get(items).status_code == 200
