"""CORS and gzip: preflights for reads and writes, and MapLibre in Chromium on a page served
from another origin drawing our style, TileJSON and tiles, reading features, and being
refused a write unless its origin is listed."""

from __future__ import annotations

import functools
import http.server
import os
import threading
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import morecantile
import pytest
from fastapi.testclient import TestClient

from app.db.session import session_scope
from app.settings import get_settings
from ingest.network import RoadAttributes, RoadLine, write_network
from ingest.raster.job import ingest_raster
from testkit.network_helpers import token
from testkit.raster_synth import synthetic_utm
from testkit.server import running_server
from tests.conftest import REPO

ELSEWHERE = "http://pages.example"
MAPLIBRE = REPO / "app" / "web" / "node_modules" / "maplibre-gl" / "dist"
PAGE = """<!doctype html>
<html><body><div id="map" style="width:600px;height:400px"></div>
<script type="module">
const q = new URLSearchParams(location.search);
const api = q.get('api'), network = q.get('network');
const result = window.result = {errors: []};
try {
  const maplibregl = await import('/maplibre/maplibre-gl.mjs');
  const listing = await (await fetch(`${api}/networks`)).json();
  const entry = listing.networks.find((n) => n.name === network);
  const map = new maplibregl.Map({container: 'map', style: entry.links.style});
  map.on('error', (e) => result.errors.push(String(e.error?.message || e.error)));
  await new Promise((resolve) => map.once('idle', resolve));
  result.rendered = map.queryRenderedFeatures({layers: ['segments']}).length;
  const items = await (await fetch(`${api}/collections/${network}-segments/items?limit=5`)).json();
  result.items = items.features.length;
  const url = `${api}/collections/${network}-segments/items/${items.features[0].id}`;
  result.etag = (await fetch(url)).headers.get('ETag');
  try {
    const patch = await fetch(url, {method: 'PATCH', body: JSON.stringify({name: 'Renamed'}),
      headers: {'Authorization': `Bearer ${q.get('token')}`, 'If-Match': result.etag,
                'Content-Type': 'application/merge-patch+json'}});
    result.patch = patch.status;
  } catch (err) {
    result.patch = `refused: ${err.message}`;
  }
} catch (err) {
  result.errors.push(String(err));
}
result.done = true;
</script></body></html>
"""


@pytest.fixture(scope="module")
def network(database_url: str) -> str:
    name = f"cors-{uuid.uuid4().hex[:8]}"
    with session_scope() as session:
        write_network(session, name, [
            RoadLine([(40.0, 10.0), (40.002, 10.0)], RoadAttributes(name="East road")),
            RoadLine([(40.0, 10.0), (40.0, 10.002)], RoadAttributes(name="North road"))])
    return name


def tile_path(network: str, z: int) -> str:
    t = morecantile.tms.get("WebMercatorQuad").tile(40.001, 10.0005, z)
    return f"/networks/{network}/tiles/{t.z}/{t.x}/{t.y}.mvt"


@contextmanager
def app_with(**env: str) -> Iterator[TestClient]:
    """A fresh app reading these settings (CORS origins are fixed when the app is built)."""
    from app.main import create_app

    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    get_settings.cache_clear()
    try:
        with TestClient(create_app()) as c:
            yield c
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k)
            else:
                os.environ[k] = v
        get_settings.cache_clear()


def preflight(client, path: str, method: str, origin: str = ELSEWHERE,
              headers: str = "") -> httpx.Response:
    ask = {"Origin": origin, "Access-Control-Request-Method": method}
    if headers:
        ask["Access-Control-Request-Headers"] = headers
    return client.options(path, headers=ask)


def test_reads_are_open_to_any_origin_writes_to_none_by_default(client, network) -> None:
    items = f"/collections/{network}-segments/items"
    ok = preflight(client, items, "GET")
    assert ok.status_code == 200 and ok.headers["access-control-allow-origin"] == "*"
    got = client.get(items, headers={"Origin": ELSEWHERE})
    assert got.headers["access-control-allow-origin"] == "*"
    exposed = got.headers["access-control-expose-headers"].split(",")
    assert {"ETag", "Location", "Content-Crs"} <= {h.strip() for h in exposed}
    tile = client.get(tile_path(network, 14), headers={"Origin": ELSEWHERE})
    assert tile.headers["access-control-allow-origin"] == "*"
    write = preflight(client, f"{items}/1", "PATCH",
                      headers="authorization,if-match,content-type")
    assert write.status_code == 400 and "access-control-allow-origin" not in write.headers
    # A read carrying a token counts as a write: no blanket "*" for credentials.
    with_token = preflight(client, items, "GET", headers="authorization")
    assert with_token.status_code == 400
    assert "access-control-allow-origin" not in client.get(
        items, headers={"Origin": ELSEWHERE, "Authorization": "Bearer x"}).headers


def test_listed_origins_may_write(database_url, network) -> None:
    item = f"/collections/{network}-segments/items/1"
    with app_with(UGVMAP_CORS_WRITE_ORIGINS=f"{ELSEWHERE}/, http://other.example") as c:
        ok = preflight(c, item, "PATCH", headers="authorization,if-match,content-type")
        assert ok.status_code == 200
        assert ok.headers["access-control-allow-origin"] == ELSEWHERE
        assert ok.headers["access-control-allow-credentials"] == "true"
        assert "PATCH" in ok.headers["access-control-allow-methods"]
        # Part 4 from a page: POST / PUT with a body in another CRS (Content-Crs).
        for method in ("POST", "PUT"):
            assert preflight(c, item, method,
                             headers="authorization,content-type,content-crs").status_code == 200
        denied = preflight(c, item, "PATCH", origin="http://evil.example",
                           headers="authorization")
        assert (denied.status_code, denied.json()["code"]) == (400, "CorsRefused")
    with app_with(UGVMAP_CORS_READ_ORIGINS="http://maps.example") as c:
        assert preflight(c, "/collections", "GET").status_code == 400
        listed = c.get("/collections", headers={"Origin": "http://maps.example"})
        assert listed.headers["access-control-allow-origin"] == "http://maps.example"


def test_gzip_for_json_geojson_and_mvt_not_for_images(client, tmp_path) -> None:
    network = f"gzip-{uuid.uuid4().hex[:8]}"
    with session_scope() as session:  # 40 parallel streets: a tile well over gzip's minimum
        write_network(session, network, [
            RoadLine([(40.0, 10.0 + i * 2e-5), (40.002, 10.0 + i * 2e-5)],
                     RoadAttributes(name=f"Street {i}")) for i in range(40)])
    raw = {"Accept-Encoding": "identity"}
    zipped = {"Accept-Encoding": "gzip"}
    for path in (f"/collections/{network}-segments/items?limit=100", "/openapi.json",
                 f"/networks/{network}/style.json"):
        big = client.get(path, headers=zipped)
        assert big.headers["content-encoding"] == "gzip", path
        assert "Accept-Encoding" in big.headers["vary"]
        plain = client.get(path, headers=raw)
        assert "content-encoding" not in plain.headers
        assert int(big.headers["content-length"]) < int(plain.headers["content-length"]), path
        assert big.json().keys() == plain.json().keys()  # the same document, decoded
    mvt = client.get(tile_path(network, 14), headers=zipped)
    assert mvt.status_code == 200 and len(mvt.content) > 500
    assert mvt.headers["content-encoding"] == "gzip"
    layer = f"gz-{uuid.uuid4().hex[:8]}"
    source, _ = synthetic_utm(tmp_path / "g.tif", width=200, height=200)
    ingest_raster([source], layer)
    png = client.get(f"/tiles/{layer}/2/0/0.png", headers=zipped)
    assert png.headers["content-type"] == "image/png"
    assert "content-encoding" not in png.headers


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    """Serves the test page and MapLibre; no request log on the test output."""

    def log_message(self, *args) -> None:
        pass


@contextmanager
def static_site(directory: Path) -> Iterator[str]:
    """A second web server on its own port: another origin than the API's."""
    handler = functools.partial(QuietHandler, directory=str(directory))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


def run_page(browser, site: str, api: str, network: str, editor: str) -> dict:
    context = browser.new_context()
    page = context.new_page()
    try:
        page.goto(f"{site}/page.html?api={api}&network={network}&token={editor}")
        page.wait_for_function("() => window.result && window.result.done", timeout=30_000)
        return page.evaluate("() => window.result")
    finally:
        context.close()


@pytest.mark.slow
def test_maplibre_on_another_origin(browser, database_url, live_server, network,
                                    tmp_path) -> None:
    if not MAPLIBRE.is_dir():
        pytest.skip("MapLibre not installed (npm ci in app/web)")
    (tmp_path / "page.html").write_text(PAGE)
    (tmp_path / "maplibre").symlink_to(MAPLIBRE)
    editor = token("editor")
    items = f"{live_server}/collections/{network}-segments/items"
    with static_site(tmp_path) as site:
        assert site.rsplit(":", 1)[1] != live_server.rsplit(":", 1)[1]
        result = run_page(browser, site, live_server, network, editor)
        assert result["errors"] == [], result
        assert result["rendered"] > 0 and result["items"] == 2
        assert result["etag"] == '"1"'  # an exposed header
        assert str(result["patch"]).startswith("refused"), result
        names = {f["properties"]["name"] for f in httpx.get(items).json()["features"]}
        assert names == {"East road", "North road"}  # the refused write changed nothing

        env = {"DATABASE_URL": database_url,
               "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"],
               "UGVMAP_CORS_WRITE_ORIGINS": site}
        with running_server(env) as trusting:
            result = run_page(browser, site, trusting, network, editor)
        assert result["errors"] == [] and result["patch"] == 200, result
        names = {f["properties"]["name"] for f in httpx.get(items).json()["features"]}
        assert "Renamed" in names
