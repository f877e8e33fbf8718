"""The web map end to end: real headless Chromium (Debian's, no Playwright download) against the
real server on localhost, with data ingested through the real CLI.

Test data with known answers: a magenta orthophoto under a small network where point A to
point B goes either along a short "Direct road" or a longer "Detour road". Slowing the direct
road down must flip the route onto the detour, which the page must show.
"""

from __future__ import annotations

import json
import os
import re

import cv2
import httpx
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import from_bounds

from cli.main import main
from tests.conftest import running_server

pytestmark = pytest.mark.slow

MAGENTA = (230, 20, 200)
# The scene sits where no other test puts data (the session database is shared): network tests
# use (10, 50). Latitude 50 keeps the metre figures below: 0.001 deg = 71.5 m east, 111 m north.
ORIGIN = (7.777, 50.0)


def at(east_deg: float, north_deg: float) -> tuple[float, float]:
    return (round(ORIGIN[0] + east_deg, 7), round(ORIGIN[1] + north_deg, 7))


RASTER_BOUNDS = (*at(-0.0006, -0.0006), *at(0.0026, 0.0018))
A, B = at(0, 0), at(0.002, 0)
DIRECT = [A, B]
DETOUR = [A, at(0, 0.001), at(0.002, 0.001), B]
SPUR = [at(0.001, 0.001), at(0.001, 0.0016)]


def cli(*args: str) -> str:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def world(live_server: str, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Ingest the magenta layer and the A/B network once for the module; an editor token."""
    folder = tmp_path_factory.mktemp("web-data")
    tif = folder / "magenta.tif"
    width, height = 640, 480
    with rasterio.open(tif, "w", driver="GTiff", width=width, height=height, count=3,
                       dtype="uint8", crs="EPSG:4326",
                       transform=from_bounds(*RASTER_BOUNDS, width, height)) as ds:
        for band, value in enumerate(MAGENTA, start=1):
            ds.write(np.full((height, width), value, np.uint8), band)
    cli("ingest", "raster", str(tif), "--layer", "web-magenta", "--title", "Magenta survey")

    def road(coords, name, road_class):
        return {"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords},
                "properties": {"name": name, "road_class": road_class, "speed_limit_kph": 50,
                               "lanes_forward": 1, "lanes_backward": 1}}

    roads = folder / "roads.geojson"
    roads.write_text(json.dumps({"type": "FeatureCollection", "features": [
        road(DIRECT, "Direct road", "residential"), road(DETOUR, "Detour road", "tertiary"),
        road(SPUR, "Spur", "service")]}))
    cli("ingest", "network", str(roads), "--network", "webnet")
    token = re.search(r"\S{20,}", cli("tokens", "create", "--role", "editor", "--name", "web"))
    assert token, "tokens create printed no token"
    return {"base": live_server, "token": token.group(0)}


def open_map(browser, world, request, tmp_path, viewport=(1100, 750), fit=True, path="/"):
    context = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("console", lambda m: m.type == "error" and print(f"browser console: {m.text}"))
    page.on("requestfailed", lambda r: print(f"request failed: {r.url} {r.failure}"))
    outside: list[str] = []
    page.on("request", lambda r: None if r.url.startswith(world["base"])
            or r.url.startswith(("data:", "blob:")) else outside.append(r.url))
    request.addfinalizer(lambda: finish(page, context, request, tmp_path, errors, outside))
    page.goto(world["base"] + path)
    page.wait_for_selector("body[data-ready=true]", timeout=20_000)
    if fit:  # the (shared) test database holds other tests' data too; look at this scene
        page.evaluate("(b) => window.ugvmap.map.fitBounds(b, {padding: 30, duration: 0})",
                      list(RASTER_BOUNDS))
    wait_idle(page)
    return page


def test_opens_on_imagery_with_roads_and_keeps_the_view_in_the_url(browser, world, request,
                                                                    tmp_path) -> None:
    """No empty world view: the page opens where a layer has roads on it; the URL keeps it."""
    far = tmp_path / "far.geojson"  # roads on another continent, with no imagery under them
    far.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"name": "Far road"},
        "geometry": {"type": "LineString", "coordinates": [[100.0, -40.0], [100.01, -40.0]]}}]}))
    cli("ingest", "network", str(far), "--network", "web-far")
    page = open_map(browser, world, request, tmp_path, fit=False)
    zoom = page.evaluate("() => window.ugvmap.map.getZoom()")
    assert zoom > 12, f"opened at zoom {zoom:.1f}: a world view, not on imagery with roads"
    view = "#map=17/" + "/".join(f"{(a + b) / 2:.5f}" for a, b in (
        (RASTER_BOUNDS[1], RASTER_BOUNDS[3]), (RASTER_BOUNDS[0], RASTER_BOUNDS[2])))
    shared = open_map(browser, world, request, tmp_path, fit=False, path="/" + view)
    lon, lat = shared.evaluate("() => window.ugvmap.map.getCenter().toArray()")
    assert abs(lon - (RASTER_BOUNDS[0] + RASTER_BOUNDS[2]) / 2) < 1e-4
    assert abs(lat - (RASTER_BOUNDS[1] + RASTER_BOUNDS[3]) / 2) < 1e-4
    assert shared.evaluate("() => window.location.hash").startswith("#map=17/")


def test_networks_that_need_a_reader_token(browser, world, request, tmp_path,
                                           database_url: str) -> None:
    """With ``UGVMAP_NETWORK_READ_ROLE`` set, the page says why no road network shows; once a
    viewer token is pasted it reloads and draws the roads, its network tile requests carrying
    the token and its raster tile requests not (they stay cacheable by the front cache)."""
    viewer = re.search(r"\S{20,}", cli("tokens", "create", "--role", "viewer", "--name", "web-r"))
    assert viewer, "tokens create printed no token"
    env = {"DATABASE_URL": database_url, "UGVMAP_NETWORK_READ_ROLE": "viewer",
           "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"]}
    with running_server(env) as base:
        context = browser.new_context(viewport={"width": 1100, "height": 750})
        request.addfinalizer(context.close)
        page = context.new_page()
        sent: list[tuple[str, str | None]] = []
        page.on("request", lambda r: sent.append((r.url, r.headers.get("authorization"))))
        page.goto(base + "/")
        page.wait_for_selector("body[data-ready=true]", timeout=20_000)
        assert "reader token" in page.locator("#status").inner_text()
        assert page.locator("#networks li").count() == 0

        page.fill("#token", viewer.group(0))
        with page.expect_navigation():
            page.locator("#token").blur()  # 'change': the page reloads with the token
        page.wait_for_selector("body[data-ready=true]", timeout=20_000)
        page.evaluate("(b) => window.ugvmap.map.fitBounds(b, {padding: 30, duration: 0})",
                      list(RASTER_BOUNDS))
        wait_idle(page)
        assert page.locator("#status").inner_text() == ""
        drawn = page.evaluate("() => window.ugvmap.map.queryRenderedFeatures("
                              "{layers: ['net-webnet-segments']}).length")
        assert drawn > 0, "no road drawn with the viewer token"
        bearer = f"Bearer {viewer.group(0)}"
        mvt = [auth for url, auth in sent if "/networks/webnet/tiles/" in url]
        assert mvt and all(auth == bearer for auth in mvt), mvt
        raster = [auth for url, auth in sent if url.startswith(f"{base}/tiles/")]
        assert raster and not any(raster), "raster tiles must not carry the token"


def plan_route(page) -> None:
    page.check("#route-active")
    page.select_option("#route-network", "webnet")


def finish(page, context, request, tmp_path, errors, outside) -> None:
    report = getattr(request.node, "rep_call", None)
    if report is not None and report.failed:
        shot = tmp_path / "failure.png"
        page.screenshot(path=str(shot), full_page=True, timeout=10_000)
        print(f"screenshot of the failed page: {shot}; page errors: {errors}")
    status = page.locator("#status").inner_text()  # the page reports map/style errors here
    context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"
    assert not status, f"the page reported: {status}"
    assert not outside, f"the page requested outside resources: {outside}"


def wait_idle(page) -> None:
    page.wait_for_function("() => { const m = window.ugvmap.map; "
                           "return m.loaded() && m.areTilesLoaded() && !m.isMoving(); }",
                           timeout=20_000)
    page.wait_for_timeout(150)  # one more frame after the last tile arrives


def colour_pixels(page, rgb: tuple[int, int, int], tolerance: int = 30) -> int:
    png = page.locator("#map canvas").screenshot()
    bgr = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR).astype(int)
    diff = np.abs(bgr - np.array(rgb[::-1])).max(axis=2)
    return int((diff <= tolerance).sum())


def click_lonlat(page, lon: float, lat: float) -> None:
    x, y = page.evaluate("([lon, lat]) => { const p = window.ugvmap.map.project([lon, lat]); "
                         "const r = window.ugvmap.map.getContainer().getBoundingClientRect(); "
                         "return [r.left + p.x, r.top + p.y]; }", [lon, lat])
    page.mouse.click(x, y)


def route_distance_m(page) -> float:
    text = page.locator("#route-result .distance").inner_text()
    value, unit = re.fullmatch(r"([\d.]+) (k?m)", text.strip()).groups()
    return float(value) * (1000 if unit == "km" else 1)


def wait_route_change(page, old_distance: str) -> None:
    """Wait for a new route summary (while routing, the old one is already gone)."""
    page.wait_for_function("(old) => { const d = document.querySelector('#route-result .distance');"
                           " return d && d.textContent !== old; }", arg=old_distance)


def test_raster_layer_is_drawn_and_toggles(browser, world, request, tmp_path) -> None:
    page = open_map(browser, world, request, tmp_path)
    entry = page.locator("#raster-layers li[data-layer=web-magenta]")
    assert "Magenta survey" in entry.inner_text()
    shown = colour_pixels(page, MAGENTA)
    canvas = page.locator("#map canvas").bounding_box()
    assert shown > 0.2 * canvas["width"] * canvas["height"], shown

    entry.locator("input.visible").uncheck()
    wait_idle(page)
    assert colour_pixels(page, MAGENTA) == 0

    entry.locator("input.visible").check()
    page.evaluate("window.ugvmap.map.jumpTo({center: [0, 0], zoom: 3})")
    wait_idle(page)
    assert colour_pixels(page, MAGENTA) == 0
    entry.locator("button.zoom").click()  # back to the layer's TileJSON bounds
    wait_idle(page)
    assert colour_pixels(page, MAGENTA) > 0.2 * canvas["width"] * canvas["height"]

    entry.locator("input.opacity").fill("0")
    wait_idle(page)
    assert colour_pixels(page, MAGENTA) == 0
    # Scale bar and cursor coordinates are there too.
    assert re.search(r"\d+\s*(m|km)", page.locator(".maplibregl-ctrl-scale").inner_text())
    page.mouse.move(canvas["x"] + canvas["width"] / 2, canvas["y"] + canvas["height"] / 2)
    shown_at = page.locator("#coords").inner_text()
    lat, lon = (float(v) for v in re.findall(r"-?\d+\.\d+", shown_at)[:2])
    assert np.allclose((lon, lat), at(0.001, 0.0006), atol=0.002)


def test_segment_click_shows_attributes_and_history(browser, world, request, tmp_path) -> None:
    page = open_map(browser, world, request, tmp_path)
    click_lonlat(page, *at(0.0005, 0))
    inspector = page.locator("#inspector")
    inspector.wait_for(state="visible")
    page.wait_for_function("document.querySelector('#f-name').value !== ''")
    assert page.locator("#f-name").input_value() == "Direct road"
    assert float(page.locator("#f-speed_limit_kph").input_value()) == 50
    assert page.locator("#f-road_class").input_value() == "residential"
    # Read-only without a token.
    assert page.locator("#f-speed_limit_kph").is_disabled()
    # The history arrives by its own request: wait for it rather than race it.
    page.wait_for_function("document.querySelector('#seg-history').innerText.trim() !== ''")
    # Nodes are drawn by kind: the spur meets the detour at a junction, the spur's end is not.
    kinds_js = ("window.ugvmap.map.queryRenderedFeatures({layers: ['net-webnet-nodes']})"
                ".map((f) => f.properties.kind)")
    page.wait_for_function(f"(() => {{ const k = {kinds_js}; "
                           "return k.includes('junction') && k.includes('endpoint'); })()")

    click_lonlat(page, *at(0.0015, 0.001))  # the detour's top edge, east of the spur
    page.wait_for_function("document.querySelector('#f-name').value === 'Detour road'")


def test_edit_speed_limit_then_route_takes_the_detour(browser, world, request,
                                                      tmp_path) -> None:
    page = open_map(browser, world, request, tmp_path)
    plan_route(page)
    click_lonlat(page, *at(0.0002, 0))
    click_lonlat(page, *at(0.0018, 0))
    page.locator("#route-result .distance").wait_for()
    before_text = page.locator("#route-result .distance").inner_text()
    before = route_distance_m(page)
    assert 100 < before < 130  # 0.0016 deg of longitude at 50 N: 114 m along the direct road
    wait_idle(page)
    assert colour_pixels(page, (31, 79, 255), tolerance=12) > 100  # the drawn route line
    page.uncheck("#route-active")

    click_lonlat(page, *at(0.001, 0))
    page.wait_for_function("document.querySelector('#f-name').value === 'Direct road'")
    page.fill("#token", world["token"])
    page.fill("#f-speed_limit_kph", "900")
    page.click("#seg-save")
    error = page.locator("#f-speed_limit_kph-error")
    error.wait_for(state="visible")
    assert "km/h" in error.inner_text()

    page.fill("#f-speed_limit_kph", "5")
    page.click("#seg-save")
    page.wait_for_function("document.querySelector('#seg-message').textContent.startsWith('Saved')")
    assert page.locator("#f-speed_limit_kph-error").inner_text() == ""
    page.wait_for_function("document.querySelector('#seg-history').textContent"
                           ".includes('speed_limit_kph: 50 → 5')")
    stored = httpx.get(f"{world['base']}/collections/webnet-segments/items/"
                       f"{page.evaluate('window.ugvmap.inspector.id')}").json()
    assert stored["properties"]["speed_limit_kph"] == 5
    # The map's vector tiles were reloaded: the drawn segment carries the new speed limit.
    page.wait_for_function(
        "(fid) => window.ugvmap.map.queryRenderedFeatures({layers: ['net-webnet-segments']})"
        ".some((f) => f.id === fid && f.properties.speed_limit_kph === 5)", arg=stored["id"])

    # The route re-plans after the save: the slow direct road is now avoided.
    wait_route_change(page, before_text)
    after = route_distance_m(page)
    assert 350 < after < 450, after
    # Put the speed back so the other tests see the original network.
    page.fill("#f-speed_limit_kph", "50")
    page.click("#seg-save")
    page.wait_for_function(
        "document.querySelector('#seg-message').textContent.includes('version 3')")


def test_stale_edit_shows_conflict_and_reload(browser, world, request, tmp_path) -> None:
    page = open_map(browser, world, request, tmp_path)
    click_lonlat(page, *at(0, 0.0005))  # the detour's west edge
    page.wait_for_function("document.querySelector('#f-name').value === 'Detour road'")
    page.fill("#token", world["token"])
    fid = page.evaluate("window.ugvmap.inspector.id")
    url = f"{world['base']}/collections/webnet-segments/items/{fid}"
    current = httpx.get(url)
    meanwhile = httpx.patch(url, json={"name": "Renamed elsewhere"},
                            headers={"Authorization": f"Bearer {world['token']}",
                                     "If-Match": current.headers["ETag"]})
    assert meanwhile.status_code == 200, meanwhile.text

    page.fill("#f-lanes_forward", "2")
    page.click("#seg-save")
    message = page.locator("#seg-message")
    page.wait_for_function("document.querySelector('#seg-message').textContent.includes('Conflict')")
    assert "not saved" in message.inner_text()
    assert httpx.get(url).json()["properties"]["lanes_forward"] == 1  # nothing changed
    page.click("#seg-reload")
    page.wait_for_function("document.querySelector('#f-name').value === 'Renamed elsewhere'")
    assert page.locator("#seg-reload").is_hidden()

    # The token is entered once per browser tab: after a reload the form is still editable.
    page.reload()
    page.wait_for_selector("body[data-ready=true]")
    assert page.locator("#token").input_value() == world["token"]


def test_route_errors_are_shown_in_words(browser, world, request, tmp_path) -> None:
    page = open_map(browser, world, request, tmp_path)
    plan_route(page)
    click_lonlat(page, *at(0.0002, 0))
    click_lonlat(page, *at(0.0024, 0.0017))  # on the magenta image, far from every road
    error = page.locator("#route-result .route-error")
    error.wait_for()
    assert "No route" in error.inner_text() and len(error.inner_text()) > 20
    # Clicking the far point removes it; with the two on-road points the route is back.
    page.locator(".task-point").nth(1).click()
    assert page.locator(".task-point").count() == 1
    click_lonlat(page, *at(0.0018, 0))
    page.locator("#route-result .distance").wait_for()
    assert route_distance_m(page) > 0


def test_phone_width_collapses_the_panel(browser, world, request, tmp_path) -> None:
    page = open_map(browser, world, request, tmp_path, viewport=(390, 800))
    assert page.locator("#panel").is_hidden()
    page.click("#panel-toggle")
    assert page.locator("#panel").is_visible()
    assert page.locator("#raster-layers li[data-layer=web-magenta]").is_visible()


def marker_labels(page) -> list[str]:
    return [t.strip() for t in page.locator(".task-point").all_inner_texts()]


def test_optimize_order_and_drag_a_point(browser, world, request, tmp_path) -> None:
    page = open_map(browser, world, request, tmp_path)
    plan_route(page)
    # Up the detour's west edge to 50.0008, back down to 50.0002, then to its top: a zig-zag
    # that visiting the two middle points the other way round avoids.
    for point in [at(0.0002, 0), at(0, 0.0008), at(0, 0.0002), at(0.0015, 0.001)]:
        click_lonlat(page, *point)
    page.locator("#route-result .distance").wait_for()
    page.wait_for_function("!document.querySelector('#route-result').textContent.includes('…')")
    zigzag_text = page.locator(".distance").inner_text()
    zigzag = route_distance_m(page)
    assert marker_labels(page) == ["1", "2", "3", "4"]

    page.check("#route-optimize")
    wait_route_change(page, zigzag_text)
    assert marker_labels(page) == ["1", "3", "2", "4"]  # labels give the visiting order
    assert route_distance_m(page) < zigzag - 100  # 2 x 67 m of back-and-forth saved

    # Drag the last point east along the detour's top: the route grows, no point is removed.
    before = page.locator(".distance").inner_text()
    box = page.locator(".task-point").nth(3).bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    tx, ty = page.evaluate("([lon, lat]) => { const p = window.ugvmap.map.project([lon, lat]);"
                           " const r = window.ugvmap.map.getContainer().getBoundingClientRect();"
                           " return [r.left + p.x, r.top + p.y]; }", at(0.002, 0.0008))
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(tx, ty, steps=8)
    page.mouse.up()
    wait_route_change(page, before)
    assert page.locator(".task-point").count() == 4
    assert route_distance_m(page) > float(before.split()[0]) + 30
