"""The painted lane boundaries in the web map: an orthophoto of the synthetic 2+2-lane road
(:class:`ingest.ipm.synthetic.LanePaint` seen from above at 0.05 m/px, with a zebra crossing),
a network along the road, ``ugvmap ingest lanes``, then the page in headless Chromium at zoom
19: the lane lines and the crossing are drawn over the imagery as the style says (dashed,
solid, road edges, the crossing in fine dashes), and listed in the legend."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import CRS, Transformer
from rasterio.transform import from_origin

from app.db.models import LANE_COLOURS, LANE_KINDS
from cli.main import main
from ingest.ipm.synthetic import Drive, LanePaint
from testkit.network_helpers import token
from testkit.raster_synth import write_tif
from testkit.server import running_server
from tests.test_web_map import finish, wait_idle

pytestmark = pytest.mark.slow

DRIVE = Drive.in_lane(LanePaint(stop_at_m=None, zebra_at_m=16.0), markers=())
RES = 0.05
HALF_M = 14.0


def cli(*args: str) -> str:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def lane_world(module_database: str, tmp_path_factory: pytest.TempPathFactory
               ) -> Iterator[dict]:
    """The road's orthophoto as layer ``web-lanes-ortho``, network ``weblanes`` along it with
    its lanes ingested from the orthophoto, and the server."""
    folder = tmp_path_factory.mktemp("web-lanes")
    east0, north0, _ = DRIVE.local_pose(10.0)
    ticks = np.arange(-HALF_M, HALF_M, RES) + RES / 2
    east, north = np.meshgrid(east0 + ticks, north0 - ticks)
    rgb = np.clip(DRIVE.texture(east, north) + 0.5, 0, 255).astype(np.uint8)
    aeqd = CRS.from_proj4(f"+proj=aeqd +lat_0={DRIVE.lat0} +lon_0={DRIVE.lon0} +ellps=WGS84 "
                          "+units=m")
    write_tif(folder / "ortho.tif", np.moveaxis(rgb, 2, 0).copy(), aeqd,
              from_origin(east0 - HALF_M, north0 + HALF_M, RES, RES))
    cli("ingest", "raster", str(folder / "ortho.tif"), "--layer", "web-lanes-ortho")
    radius = DRIVE.radius_m + DRIVE.road_offset_m
    az = np.radians(DRIVE.start_deg) + np.linspace(-2.0, 22.0, 40) / DRIVE.radius_m
    lon, lat = DRIVE.to_lonlat(radius * np.sin(az), radius * np.cos(az))
    road = folder / "road.geojson"
    road.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {},
        "geometry": {"type": "LineString", "coordinates": np.column_stack([lon, lat]).tolist()}}]}))
    cli("ingest", "network", str(road), "--network", "weblanes")
    said = cli("ingest", "lanes", "--layer", "web-lanes-ortho", "--network", "weblanes")
    assert "on 1 of 1 segments" in said and "1 crossings" in said, said
    centre = Transformer.from_crs(aeqd, "EPSG:4326", always_xy=True).transform(east0, north0)
    env = {"DATABASE_URL": module_database,
           "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"]}
    with running_server(env) as base:
        yield {"base": base, "centre": list(centre), "token": token("editor")}


def test_lane_lines_are_drawn_over_the_imagery(browser, lane_world, request,
                                               tmp_path: Path) -> None:
    context = browser.new_context(viewport={"width": 900, "height": 650})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    outside: list[str] = []
    page.on("request", lambda r: None if r.url.startswith(lane_world["base"])
            or r.url.startswith(("data:", "blob:")) else outside.append(r.url))
    schema_read: list[str] = []
    page.on("request", lambda r: schema_read.append(r.url) if r.url.endswith("/schema")
            else None)
    request.addfinalizer(lambda: finish(page, context, request, tmp_path, errors, outside))
    page.goto(lane_world["base"] + "/")
    page.wait_for_selector("body[data-ready=true]", timeout=20_000)
    page.evaluate("(c) => window.ugvmap.map.jumpTo({center: c, zoom: 19})", lane_world["centre"])
    wait_idle(page)
    layers = page.evaluate("() => window.ugvmap.map.getStyle().layers.map((l) => l.id)"
                           ".filter((id) => id.startsWith('net-weblanes-lanes'))")
    assert layers == ["net-weblanes-lanes-solid", "net-weblanes-lanes-dashed",
                      "net-weblanes-lanes-stop", "net-weblanes-lanes-crosswalk"]
    drawn = page.evaluate("(ids) => window.ugvmap.map.queryRenderedFeatures({layers: ids})"
                          ".map((f) => [f.layer.id, f.properties.kind, f.properties.colour])",
                          layers)
    kinds = {(layer, kind, colour) for layer, kind, colour in drawn}
    assert ("net-weblanes-lanes-dashed", "dashed", "white") in kinds, kinds
    assert ("net-weblanes-lanes-solid", "solid", "yellow") in kinds, kinds
    assert ("net-weblanes-lanes-solid", "road_edge", "white") in kinds, kinds
    assert ("net-weblanes-lanes-crosswalk", "crosswalk", "white") in kinds, kinds
    assert page.evaluate("(id) => window.ugvmap.map.getPaintProperty(id, 'line-dasharray')",
                         "net-weblanes-lanes-dashed") == [3, 3]
    assert "lane lines from the paint" in page.locator("#legend").inner_text()
    # a click on a dashed line says what it is and where its feature is
    x, y = page.evaluate(
        "() => { const m = window.ugvmap.map; const [f] = m.queryRenderedFeatures("
        "{layers: ['net-weblanes-lanes-dashed']}); const g = f.geometry; "
        "const c = g.type === 'MultiLineString' ? g.coordinates.flat() : g.coordinates; "
        "const p = m.project(c[Math.floor(c.length / 2)]); return [p.x, p.y]; }")
    page.locator("#map canvas").click(position={"x": x, "y": y})
    info = page.locator(".lane-info")
    info.wait_for(timeout=5_000)
    assert "dashed" in info.inner_text() and "the paint" in info.inner_text()
    href = info.locator("a").get_attribute("href")
    assert "/collections/weblanes-lanes/items/" in href
    # the kinds and colours offered are the collection schema's, read from the server
    assert schema_read and all(url.endswith("/collections/weblanes-lanes/schema")
                               for url in schema_read), schema_read
    offered = [info.locator(f"select[name={name}] option").evaluate_all(
        "(os) => os.map((o) => o.value)") for name in ("kind", "colour")]
    assert offered == [list(LANE_KINDS), list(LANE_COLOURS)]
    # ...and, with an editor token, changes its kind: refused and said without one, then
    # saved as the next version of what the popup read, and drawn solid
    version = httpx.get(lane_world["base"] + href).json()["properties"]["version"]
    info.locator("select[name=kind]").select_option("solid")
    info.locator("button", has_text="Save").click()
    page.wait_for_function("() => /Not saved/.test("
                           "document.querySelector('.lane-said').textContent)", timeout=10_000)
    page.fill("#token", lane_world["token"])
    info.locator("button", has_text="Save").click()
    page.wait_for_function("() => /Saved \\(version/.test("
                           "document.querySelector('.lane-said').textContent)", timeout=10_000)
    saved = httpx.get(lane_world["base"] + href).json()["properties"]
    assert (saved["kind"], saved["version"]) == ("solid", version + 1)
    history = httpx.get(lane_world["base"] + href + "/history").json()["edits"]
    assert history[-1]["new"] == {"kind": "solid"} and history[-1]["conditional"] is True
    page.wait_for_function(
        "(id) => window.ugvmap.map.queryRenderedFeatures({layers: ['net-weblanes-lanes-solid']})"
        ".some((f) => f.id === id && f.properties.kind === 'solid')",
        arg=int(href.rsplit("/", 1)[1]), timeout=15_000)
    page.uncheck("#networks li[data-network=weblanes] input.visible")
    assert page.evaluate("(id) => window.ugvmap.map.getLayoutProperty(id, 'visibility')",
                         "net-weblanes-lanes-dashed") == "none"
