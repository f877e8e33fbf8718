"""Versioned tile URLs: immutable with the current version, short-lived otherwise; a re-ingest
or an edit changes the URL; tiles outside coverage are tiny."""

from __future__ import annotations

import uuid
from urllib.parse import parse_qs, urlsplit

import morecantile
import numpy as np
import pytest

from app.db.session import session_scope
from app.network.collections import network_row
from app.network.tiles import network_token
from ingest.raster.job import ingest_raster
from testkit.network_helpers import bearer, grid_network
from testkit.raster_synth import UTM33, decode_rgba, synthetic_utm, tiles_around, write_tif

TMS = morecantile.tms.get("WebMercatorQuad")
IMMUTABLE = "public, max-age=31536000, immutable"


def _tile_path(template: str, z: int, x: int, y: int) -> str:
    """A TileJSON template filled in, as a path + query for the test client."""
    url = urlsplit(template.replace("{z}", str(z)).replace("{x}", str(x)).replace("{y}", str(y)))
    return f"{url.path}?{url.query}" if url.query else url.path


def _layer(client, tmp_path, colour: int) -> tuple[str, dict]:
    _, transform = synthetic_utm(tmp_path / "unused.tif", width=10, height=10)
    data = np.zeros((3, 300, 300), np.uint8)
    data[colour] = 200
    name = f"v-{uuid.uuid4().hex[:10]}"
    ingest_raster([write_tif(tmp_path / f"c{colour}.tif", data, UTM33, transform)], name)
    return name, client.get(f"/layers/{name}/tilejson.json").json()


def test_versioned_raster_tile_is_immutable_and_reingest_changes_the_url(client,
                                                                         tmp_path) -> None:
    name, tj = _layer(client, tmp_path, 0)
    template = tj["tiles"][0]
    assert parse_qs(urlsplit(template).query)["v"]
    assert client.get(f"/layers/{name}").json()["links"]["tiles"] == template
    zoom = tj["maxzoom"]
    w, s, e, n = tj["bounds"]
    x, y, _, _ = tiles_around((w + e) / 2, (s + n) / 2, zoom, n=1)
    versioned = _tile_path(template, zoom, x, y)

    first = client.get(versioned)
    assert first.status_code == 200
    assert first.headers["cache-control"] == IMMUTABLE
    etag = first.headers["etag"]
    assert etag.startswith('"') and not etag.startswith("W/")  # strong
    assert client.get(versioned, headers={"If-None-Match": etag}).status_code == 304
    plain = client.get(f"/tiles/{name}/{zoom}/{x}/{y}.png")  # unversioned: as before
    assert plain.headers["cache-control"] == "public, max-age=60"
    assert plain.headers["etag"] == etag and plain.content == first.content

    blue = np.zeros((3, 300, 300), np.uint8)
    blue[2] = 200
    _, transform = synthetic_utm(tmp_path / "unused2.tif", width=10, height=10)
    ingest_raster([write_tif(tmp_path / "blue.tif", blue, UTM33, transform)], name)
    template2 = client.get(f"/layers/{name}/tilejson.json").json()["tiles"][0]
    assert template2 != template  # a re-ingest hands out new URLs

    stale = client.get(versioned)  # a page that read the old TileJSON
    assert stale.status_code == 200
    assert stale.headers["cache-control"] == "public, max-age=60"  # never immutable
    assert stale.headers["etag"] != etag
    rgba = decode_rgba(stale.content)
    valid = rgba[rgba[..., 3] == 255]
    assert np.median(valid[:, 2]) > 150 > 50 > np.median(valid[:, 0])  # the current (blue)
    fresh = client.get(_tile_path(template2, zoom, x, y))
    assert fresh.headers["cache-control"] == IMMUTABLE
    assert fresh.content == stale.content
    assert client.get(f"{versioned.split('?')[0]}?v=bogus").headers["cache-control"] \
        == "public, max-age=60"
    assert client.get(f"/layers/{name}/tilejson.json").headers["cache-control"] == "no-cache"


def test_tiles_outside_coverage_are_tiny_and_cacheable(client, tmp_path) -> None:
    name, _ = _layer(client, tmp_path, 1)
    for fmt, limit in (("png", 1000), ("webp", 200), ("jpg", 2000)):
        template = client.get(f"/layers/{name}/tilejson.json?format={fmt}").json()["tiles"][0]
        resp = client.get(_tile_path(template, 3, 0, 0))  # far from the layer
        assert resp.status_code == 200, fmt
        assert len(resp.content) < limit, (fmt, len(resp.content))
        assert resp.headers["cache-control"] == IMMUTABLE
        rgba = decode_rgba(resp.content)
        if fmt == "jpg":
            assert rgba[..., :3].min() > 240  # white, the map background
        else:
            assert rgba[..., 3].max() == 0
    big = client.get(f"/tiles/{name}/3/0/0@2x.png")
    assert decode_rgba(big.content).shape == (512, 512, 4) and len(big.content) < 2000


@pytest.fixture()
def grid(database_url: str):
    return grid_network()


def test_versioned_vector_tile_is_immutable_and_an_edit_changes_the_token(client,
                                                                          grid) -> None:
    def token() -> str:
        with session_scope() as session:
            return network_token(network_row(session, grid.network))

    t = TMS.tile(10.001, 50.001, 14)
    path = f"/networks/{grid.network}/tiles/14/{t.x}/{t.y}.mvt"
    before = token()
    versioned = client.get(f"{path}?v={before}")
    assert versioned.headers["cache-control"] == IMMUTABLE
    assert versioned.headers["etag"] == f'"{before}"'
    assert client.get(f"{path}?v={before}",
                      headers={"If-None-Match": f'"{before}"'}).status_code == 304
    assert client.get(path).headers["cache-control"] == "no-cache"

    items = f"/collections/{grid.network}-segments/items"
    fid = client.get(items, params={"limit": 1}).json()["features"][0]["id"]
    r = client.patch(f"{items}/{fid}", json={"name": "Renamed"},
                     headers={**bearer("editor"), "If-Match": '"1"'})
    assert r.status_code == 200
    after = token()
    assert after != before
    stale = client.get(f"{path}?v={before}")
    assert stale.headers["cache-control"] == "no-cache"
    assert b"Renamed" in stale.content
    assert client.get(f"{path}?v={after}").headers["cache-control"] == IMMUTABLE


def test_private_networks_are_never_publicly_cached(client, grid, monkeypatch) -> None:
    from app.settings import get_settings

    monkeypatch.setenv("UGVMAP_NETWORK_READ_ROLE", "viewer")
    get_settings.cache_clear()
    try:
        with session_scope() as session:
            current = network_token(network_row(session, grid.network))
        t = TMS.tile(10.001, 50.001, 14)
        resp = client.get(f"/networks/{grid.network}/tiles/14/{t.x}/{t.y}.mvt?v={current}",
                          headers=bearer("viewer"))
        assert resp.status_code == 200
        assert resp.headers["cache-control"] == "private, max-age=31536000, immutable"
    finally:
        monkeypatch.delenv("UGVMAP_NETWORK_READ_ROLE")
        get_settings.cache_clear()
