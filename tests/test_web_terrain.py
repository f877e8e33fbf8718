"""The web map's terrain controls in headless Chromium: an elevation layer drawn as a hillshade
overlay, its slope ramp with the legend, and the 3D terrain toggle fed by Terrarium tiles."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
from pyproj import Transformer
from rasterio.transform import from_origin

from ingest.raster.job import ingest_raster
from testkit.raster_synth import UTM33, utm_origin
from testkit.server import running_server
from testkit.terrain_synth import hills, write_dem
from tests.test_web_map import finish, wait_idle

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def terrain_world(module_database: str, tmp_path_factory: pytest.TempPathFactory
                  ) -> Iterator[dict]:
    """A hilly DEM (300-420 m) as elevation layer ``web-dem``, and the server."""
    folder = tmp_path_factory.mktemp("web-terrain")
    e, n = utm_origin(15.4, 48.2)
    transform = from_origin(round(e), round(n), 2.0, 2.0)
    write_dem(folder / "dem.tif", hills((transform.c, transform.f - 300)), UTM33, transform,
              400, 300)
    ingest_raster([folder / "dem.tif"], "web-dem", title="Hills", kind="elevation")
    to_lonlat = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)
    west, north = to_lonlat.transform(transform.c, transform.f)
    east, south = to_lonlat.transform(transform.c + 800, transform.f - 600)
    env = {"DATABASE_URL": module_database,
           "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"]}
    with running_server(env) as base:
        yield {"base": base, "bounds": [west, south, east, north]}


def test_terrain_toggle_hillshade_and_slope(browser, terrain_world, request,
                                            tmp_path: Path) -> None:
    # Small: SwiftShader draws every 3D frame on the CPU.
    context = browser.new_context(viewport={"width": 760, "height": 480})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    outside: list[str] = []
    page.on("request", lambda r: None if r.url.startswith(terrain_world["base"])
            or r.url.startswith(("data:", "blob:")) else outside.append(r.url))
    tiles: list[tuple[str, int]] = []
    page.on("response", lambda r: tiles.append((r.url, r.status)) if "/tiles/web-dem/" in r.url
            else None)
    request.addfinalizer(lambda: finish(page, context, request, tmp_path, errors, outside))
    page.goto(terrain_world["base"] + "/")
    page.wait_for_selector("body[data-ready=true]", timeout=20_000)
    page.evaluate("(b) => window.ugvmap.map.fitBounds(b, {padding: 30, duration: 0})",
                  terrain_world["bounds"])
    wait_idle(page)
    entry = page.locator("#raster-layers li[data-layer=web-dem]")
    assert "Hills (elevation)" in entry.inner_text()
    # The overlay is the hillshade (an elevation layer's plain tile), over what lies below.
    assert any("render=" not in u and s == 200 for u, s in tiles), tiles
    assert page.evaluate("() => window.ugvmap.map.getPaintProperty('raster-web-dem', "
                         "'raster-opacity')") == pytest.approx(0.6)

    # A 3D map keeps drawing frames in SwiftShader: wait for tiles, not for idleness.
    with page.expect_response(lambda r: "render=terrarium" in r.url, timeout=20_000) as dem:
        entry.locator("input.terrain-3d").check()
    assert dem.value.status == 200
    page.wait_for_selector("body[data-terrain=web-dem]")
    assert page.evaluate("() => window.ugvmap.map.getTerrain().source") == "dem-web-dem"
    assert page.evaluate("() => window.ugvmap.map.getPitch()") == pytest.approx(60)
    centre = [(terrain_world["bounds"][0] + terrain_world["bounds"][2]) / 2,
              (terrain_world["bounds"][1] + terrain_world["bounds"][3]) / 2]
    page.wait_for_function("(c) => window.ugvmap.map.queryTerrainElevation(c) > 100",
                           arg=centre, timeout=20_000)
    lifted = page.evaluate("(c) => window.ugvmap.map.queryTerrainElevation(c)", centre)
    assert 250 < lifted < 1.5 * 420 + 1, lifted  # the DEM's heights (times the exaggeration)

    with page.expect_response(lambda r: "render=slope" in r.url, timeout=20_000) as slope:
        entry.locator("select.render").select_option("slope")
    assert slope.value.status == 200
    assert entry.locator(".slope-legend").is_visible()
    assert "60°" in entry.locator(".slope-legend").inner_text()

    entry.locator("input.terrain-3d").uncheck()
    page.wait_for_selector("body[data-terrain='']", state="attached")
    assert page.evaluate("() => window.ugvmap.map.getTerrain()") is None
