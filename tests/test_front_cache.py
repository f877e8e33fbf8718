"""The shipped nginx front cache (cli/ops/frontcache/cache-policy.conf) in front of a real server:
versioned tiles are HITs from the second request on, a re-ingest's new URL is a MISS, and
nothing that may change or that needs a token is kept."""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import httpx
import morecantile
import numpy as np
import pytest

from cli.ops.frontcache.nginx import FrontCache, FrontCacheError, find_nginx
from ingest.raster.job import ingest_raster
from testkit.network_helpers import bearer, grid_network
from testkit.raster_synth import UTM33, synthetic_utm, tiles_around, write_tif
from testkit.server import free_port

TMS = morecantile.tms.get("WebMercatorQuad")


def _nginx_available() -> bool:
    try:
        find_nginx()
        return True
    except FrontCacheError:
        return False


pytestmark = pytest.mark.skipif(
    not _nginx_available(), reason="nginx is not installed (scripts/setup.sh installs it)")


@pytest.fixture(scope="module")
def front(live_server: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    upstream = live_server.removeprefix("http://")
    with FrontCache(tmp_path_factory.mktemp("front"), "127.0.0.1", free_port(),
                    upstream) as cache:
        yield cache.url


def _ingest(tmp_path, name: str, channel: int) -> None:
    _, transform = synthetic_utm(tmp_path / "unused.tif", width=10, height=10)
    data = np.zeros((3, 300, 300), np.uint8)
    data[channel] = 200
    ingest_raster([write_tif(tmp_path / f"c{channel}.tif", data, UTM33, transform)], name)


def _tile_url(front: str, name: str) -> str:
    tj = httpx.get(f"{front}/layers/{name}/tilejson.json").json()
    assert tj["tiles"][0].startswith(front)  # the TileJSON names the front door
    w, s, e, n = tj["bounds"]
    x, y, _, _ = tiles_around((w + e) / 2, (s + n) / 2, tj["maxzoom"], n=1)
    return tj["tiles"][0].format(z=tj["maxzoom"], x=x, y=y)


def test_versioned_tile_is_a_hit_and_a_reingest_url_a_miss(front: str, tmp_path) -> None:
    name = f"fc-{uuid.uuid4().hex[:8]}"
    _ingest(tmp_path, name, 0)
    url = _tile_url(front, name)
    first, second = httpx.get(url), httpx.get(url)
    assert (first.status_code, second.status_code) == (200, 200)
    assert (first.headers["x-cache-status"], second.headers["x-cache-status"]) == ("MISS", "HIT")
    assert second.content == first.content
    assert second.headers["cache-control"] == "public, max-age=31536000, immutable"
    assert second.headers["etag"] == first.headers["etag"]

    _ingest(tmp_path, name, 2)
    new_url = _tile_url(front, name)
    assert new_url != url
    fresh = httpx.get(new_url)
    assert fresh.headers["x-cache-status"] == "MISS"
    assert fresh.content != first.content
    assert httpx.get(new_url).headers["x-cache-status"] == "HIT"


def test_nothing_changing_or_private_is_kept(front: str, database_url: str) -> None:
    grid = grid_network()
    t = TMS.tile(10.001, 50.001, 14)
    mvt = f"{front}/networks/{grid.network}/tiles/14/{t.x}/{t.y}.mvt"
    httpx.get(mvt)
    assert httpx.get(mvt).headers["x-cache-status"] == "MISS"  # no-cache without ?v=
    assert httpx.get(f"{front}/layers").headers["x-cache-status"] == "MISS"
    with_token = httpx.get(mvt, headers=bearer("viewer"))
    assert with_token.headers["x-cache-status"] == "BYPASS"


def test_a_broken_config_is_one_clear_error(tmp_path) -> None:
    cache = FrontCache(tmp_path, "127.0.0.1", free_port(), "127.0.0.1:notaport")
    with pytest.raises(FrontCacheError, match="nginx rejected"):
        cache.__enter__()
