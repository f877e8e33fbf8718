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
from collections.abc import Iterator

import cv2
import httpx
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import from_bounds

from cli.main import main
from testkit.server import running_server

pytestmark = pytest.mark.slow

MAGENTA = (230, 20, 200)
# The module has a database of its own (``web_server``); the scene still sits where no other
# test puts data (network tests use (10, 50)). Latitude 50 keeps the metre figures below:
# 0.001 deg = 71.5 m east, 111 m north.
ORIGIN = (7.777, 50.0)


def at(east_deg: float, north_deg: float) -> tuple[float, float]:
    return (round(ORIGIN[0] + east_deg, 7), round(ORIGIN[1] + north_deg, 7))


RASTER_BOUNDS = (*at(-0.0006, -0.0006), *at(0.0026, 0.0018))
A, B = at(0, 0), at(0.002, 0)
DIRECT = [A, B]
DETOUR = [A, at(0, 0.001), at(0.002, 0.001), B]
SPUR = [at(0.001, 0.001), at(0.001, 0.0016)]
# A road extraction left unconnected: unclassified (as extracted roads are), on the imagery.
ISLAND = [at(0.0021, -0.0004), at(0.0025, -0.0004)]


def cli(*args: str) -> str:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def web_server(module_database: str) -> Iterator[str]:
    """The real server on the module's own database: the page draws every layer and network
    in the database, so on the session's one (all the other modules' data) each page took
    three to five times as long to settle."""
    with running_server({"DATABASE_URL": module_database,
                         "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"]}) as base:
        yield base


@pytest.fixture(scope="module")
def world(web_server: str, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
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
        road(SPUR, "Spur", "service"), road(ISLAND, "Island track", "unclassified")]}))
    cli("ingest", "network", str(roads), "--network", "webnet")
    token = re.search(r"\S{20,}", cli("tokens", "create", "--role", "editor", "--name", "web"))
    assert token, "tokens create printed no token"
    return {"base": web_server, "token": token.group(0)}


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
    if fit:  # the database holds the review scene and 'web-far' too; look at this one
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
                                           module_database: str) -> None:
    """With ``UGVMAP_NETWORK_READ_ROLE`` set, the page says why no road network shows; once a
    viewer token is pasted it reloads and draws the roads, its network tile requests carrying
    the token and its raster tile requests not (they stay cacheable by the front cache)."""
    viewer = re.search(r"\S{20,}", cli("tokens", "create", "--role", "viewer", "--name", "web-r"))
    assert viewer, "tokens create printed no token"
    env = {"DATABASE_URL": module_database, "UGVMAP_NETWORK_READ_ROLE": "viewer",
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


def screen(page, lon: float, lat: float) -> tuple[float, float]:
    """Page coordinates of a lon/lat on the map."""
    x, y = page.evaluate("([lon, lat]) => { const p = window.ugvmap.map.project([lon, lat]); "
                         "const r = window.ugvmap.map.getContainer().getBoundingClientRect(); "
                         "return [r.left + p.x, r.top + p.y]; }", [lon, lat])
    return x, y


def click_lonlat(page, lon: float, lat: float) -> None:
    page.mouse.click(*screen(page, lon, lat))


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
    # The scale bar is there too.
    assert re.search(r"\d+\s*(m|km)", page.locator(".maplibregl-ctrl-scale").inner_text())


def test_coordinate_readout_is_lon_lat_and_pastes_into_the_api(browser, world, request,
                                                               tmp_path) -> None:
    """The readout says lon,lat in that order, as the API, the CLI's --points and the error
    messages do: pasted into a route request it finds the road under the cursor (it read
    "lat, lon" once, which gave "no road within 10000 m")."""
    page = open_map(browser, world, request, tmp_path)
    target = at(0.0011, 0)  # on the Direct road
    page.mouse.move(*screen(page, *target))
    shown = page.locator("#coords").inner_text()
    found = re.fullmatch(r"lon,lat (-?\d+\.\d{6}),(-?\d+\.\d{6})\s+z\d+\.\d", shown.strip())
    assert found, shown
    pair = f"{found.group(1)},{found.group(2)}"
    assert np.allclose([float(v) for v in pair.split(",")], target, atol=2e-6)
    near = httpx.get(f"{world['base']}/networks/webnet/route",
                     params={"points": f"{pair};{B[0]},{B[1]}"}, timeout=30)
    assert near.status_code == 200, near.text
    assert near.json()["waypoints"][0]["distance"] < 1.0  # snapped right under the cursor


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
    # Nodes are drawn by kind, one style layer each: the spur meets the detour at a junction
    # (orange layer), the spur's end is a plain node (grey layer, from z16).
    kinds_js = ("window.ugvmap.map.queryRenderedFeatures({layers: ['net-webnet-nodes', "
                "'net-webnet-nodes-junctions', 'net-webnet-nodes-traffic-lights']})"
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

    sent: list[dict[str, str]] = []
    page.on("request", lambda r: sent.append(r.headers) if r.method == "PATCH" else None)
    page.fill("#f-lanes_forward", "2")
    page.click("#seg-save")
    message = page.locator("#seg-message")
    page.wait_for_function("document.querySelector('#seg-message').textContent.includes('Conflict')")
    assert "not saved" in message.inner_text()
    assert httpx.get(url).json()["properties"]["lanes_forward"] == 1  # nothing changed
    # The web map names the version it showed (If-Match), whatever UGVMAP_IF_MATCH allows.
    assert sent and sent[0]["if-match"] == current.headers["ETag"]
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
    tx, ty = screen(page, *at(0.002, 0.0008))
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(tx, ty, steps=8)
    page.mouse.up()
    wait_route_change(page, before)
    assert page.locator(".task-point").count() == 4
    assert route_distance_m(page) > float(before.split()[0]) + 30


# -- review of an extracted network ------------------------------------------------------
# A network as road extraction leaves it, away from the A/B scene: short unclassified
# segments with a confidence each. Rows (metres north of REVIEW at 50 N: 0.0004 deg = 44 m):
# A (confidences 0.1, 0.3, 0.7, 0.9) for colouring and filtering, B (4) for a box edit,
# C (3) for a conflict, D (a chain of 3) for a box delete, E one one-way road (not extracted).
REVIEW = (7.790, 50.0)


def rv(east_deg: float, north_deg: float) -> tuple[float, float]:
    return (round(REVIEW[0] + east_deg, 7), round(REVIEW[1] + north_deg, 7))


REVIEW_BOUNDS = (*rv(-0.0002, -0.0002), *rv(0.002, 0.0018))
ROWS = {
    "A": (0.0, [0.1, 0.3, 0.7, 0.9]),
    "B": (0.0004, [0.2, 0.4, 0.6, 0.8]),
    "C": (0.0008, [0.5, 0.5, 0.5]),
}
D_CHAIN = [rv(0, 0.0012), rv(0.0005, 0.0012), rv(0.001, 0.0012), rv(0.0015, 0.0012)]
E_ONEWAY = [rv(0, 0.0016), rv(0.0008, 0.0016)]


def row_segment(north: float, k: int) -> list[tuple[float, float]]:
    """The k-th 21 m segment of a row (0.0005 deg apart, so none touches the next)."""
    return [rv(0.0005 * k, north), rv(0.0005 * k + 0.0003, north)]


@pytest.fixture(scope="module")
def review(world: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Import the extracted-looking network 'webrev' and set its confidences in the database
    as extraction writes them; returns segment ids by row ({"A": [...], ..., "E": [id]})."""
    from sqlalchemy import text

    from app.db.session import session_scope

    roads = [(row_segment(north, k), f"{row}{k}", c, {})
             for row, (north, confs) in ROWS.items() for k, c in enumerate(confs)]
    roads += [(D_CHAIN[k:k + 2], f"D{k}", 0.3, {}) for k in range(3)]
    roads.append((E_ONEWAY, "E0", None, {"oneway": "forward", "lanes_backward": 0}))
    path = tmp_path_factory.mktemp("web-review") / "extracted.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": {"type": "LineString", "coordinates": coords},
         "properties": {"name": name, "road_class": "unclassified", "lanes_forward": 1,
                        "lanes_backward": 1, **props}}
        for coords, name, _, props in roads]}))
    cli("ingest", "network", str(path), "--network", "webrev")
    ids: dict[str, list[int]] = {}
    with session_scope() as s:
        for _, name, confidence, _ in roads:
            fid = s.execute(text(
                "UPDATE road_segments SET confidence = :c WHERE name = :name AND network_id = "
                "(SELECT id FROM networks WHERE name = 'webrev') RETURNING id"),
                {"c": confidence, "name": name}).scalar_one()
            ids.setdefault(name[0], []).append(fid)
    return {**world, "ids": ids}


def open_review(browser, review, request, tmp_path):
    page = open_map(browser, review, request, tmp_path, fit=False)
    page.evaluate("(b) => window.ugvmap.map.fitBounds(b, {padding: 20, duration: 0})",
                  list(REVIEW_BOUNDS))
    wait_idle(page)
    return page


def drawn(page, layer: str = "net-webrev-segments") -> dict[int, dict]:
    """Properties of the segments drawn on a layer, by id."""
    return {f["id"]: f["properties"] for f in page.evaluate(
        "(layer) => window.ugvmap.map.queryRenderedFeatures({layers: [layer]})"
        ".map((f) => ({id: f.id, properties: f.properties}))", layer)}


def pixel(page, lon: float, lat: float) -> tuple[int, int, int]:
    """The RGB colour the map canvas shows at a lon/lat."""
    x, y = page.evaluate("([lon, lat]) => { const p = window.ugvmap.map.project([lon, lat]); "
                         "return [Math.round(p.x), Math.round(p.y)]; }", [lon, lat])
    png = page.locator("#map canvas").screenshot()
    bgr = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    b, g, r = (int(v) for v in bgr[y, x])
    return r, g, b


def box_select(page, corner_a: tuple[float, float], corner_b: tuple[float, float]) -> None:
    """Shift-drag a box between two lon/lat corners."""
    (x0, y0), (x1, y1) = screen(page, *corner_a), screen(page, *corner_b)
    page.keyboard.down("Shift")
    page.mouse.move(x0, y0)
    page.mouse.down()
    page.mouse.move(x1, y1, steps=6)
    page.mouse.up()
    page.keyboard.up("Shift")


def middle(coords) -> tuple[float, float]:
    (a, b), (c, d) = coords[0], coords[-1]
    return (a + c) / 2, (b + d) / 2


def stored(ids: list[int]) -> dict[int, tuple]:
    """(version, speed, class, lanes_forward, name) per segment id, from the database."""
    from sqlalchemy import text

    from app.db.session import session_scope

    with session_scope() as s:
        rows = s.execute(text("SELECT id, version, speed_limit_kph, road_class, lanes_forward, "
                              "name FROM road_segments WHERE id = ANY(:ids)"),
                         {"ids": ids}).all()
    return {r[0]: tuple(r[1:]) for r in rows}


def history_rows(ids: list[int]) -> list[tuple]:
    """(segment, action, version_from, version_to) of the segments' edits, in order."""
    from sqlalchemy import text

    from app.db.session import session_scope

    with session_scope() as s:
        return [tuple(r) for r in s.execute(text(
            "SELECT segment_id, action, version_from, version_to FROM segment_edits "
            "WHERE segment_id = ANY(:ids) ORDER BY id"), {"ids": ids})]


def close(rgb: tuple[int, int, int], expected: tuple[int, int, int], tolerance: int = 30) -> bool:
    return max(abs(a - b) for a, b in zip(rgb, expected, strict=True)) <= tolerance


def test_confidence_colours_filter_and_one_way_arrows(browser, review, request,
                                                      tmp_path) -> None:
    page = open_review(browser, review, request, tmp_path)
    a_ids = review["ids"]["A"]
    # One-way arrows on the one-way road only.
    arrows = drawn(page, "net-webrev-oneway")
    assert set(arrows) == set(review["ids"]["E"]), arrows
    # Colour by confidence: red where the model was unsure (0.1), green where sure (0.9),
    # interpolated through the legend's stops (0 #d7191c, 0.5 #fdae61, 0.75 #ffffbf, 1 #1a9641).
    page.select_option("#net-style", "confidence")
    wait_idle(page)
    assert "not extracted" in page.locator("#legend").inner_text()
    low = pixel(page, *middle(row_segment(0.0, 0)))
    high = pixel(page, *middle(row_segment(0.0, 3)))
    assert close(low, (223, 55, 42)), low
    assert close(high, (118, 192, 115)), high
    # The filter: only extracted segments below 0.5 stay drawn (Row A's 0.1 and 0.3, ...);
    # the not-extracted one-way road goes too.
    page.locator("#conf-max").fill("0.5")
    assert page.locator("#conf-filter").is_checked()
    assert page.locator("#conf-value").inner_text() == "0.50"
    wait_idle(page)
    shown = drawn(page)
    assert shown and all(p["confidence"] < 0.5 for p in shown.values()), shown
    assert {a_ids[0], a_ids[1]} <= set(shown) and not {a_ids[2], a_ids[3]} & set(shown)
    assert not drawn(page, "net-webrev-oneway")
    page.locator("#conf-max").fill("0.95")
    wait_idle(page)
    assert set(a_ids) <= set(drawn(page))
    page.uncheck("#conf-filter")
    wait_idle(page)
    assert set(review["ids"]["E"]) <= set(drawn(page))


def test_bulk_edit_of_a_box_selection(browser, review, request, tmp_path) -> None:
    """Shift-drag a box over Row B, set speed and class on all four: each segment gets its
    own new version and history row; the map redraws them; 'hide edited' then hides them."""
    page = open_review(browser, review, request, tmp_path)
    page.fill("#token", review["token"])
    b_ids = review["ids"]["B"]
    box_select(page, rv(-0.0001, 0.0003), rv(0.0019, 0.0005))
    page.locator("#bulk").wait_for(state="visible")
    assert page.locator("#bulk-title").inner_text().startswith("4 segments selected")
    assert sorted(page.evaluate("window.ugvmap.selection.list().map((s) => s.id)")) == b_ids
    page.fill("#b-speed_limit_kph", "30")
    page.fill("#b-road_class", "residential")
    page.click("#bulk-apply")
    page.wait_for_function("document.querySelector('#bulk-message').textContent"
                           ".startsWith('Saved 4 of 4')")
    assert stored(b_ids) == {fid: (2, 30.0, "residential", 1, f"B{k}")
                             for k, fid in enumerate(b_ids)}
    # Four requests in flight at once: their rows come in any order, one per segment.
    assert sorted(history_rows(b_ids)) == [(fid, "update", 1, 2) for fid in b_ids]
    # The tiles were reloaded: the drawn segments carry the new values and versions.
    page.wait_for_function(
        "(ids) => { const f = window.ugvmap.map.queryRenderedFeatures("
        "{layers: ['net-webrev-segments']}).filter((f) => ids.includes(f.id));"
        " return f.length >= ids.length && f.every((x) => x.properties.speed_limit_kph === 30"
        " && x.properties.version === 2); }", arg=b_ids)
    page.check("#hide-edited")
    wait_idle(page)
    shown = drawn(page)
    assert not set(b_ids) & set(shown) and set(review["ids"]["A"]) <= set(shown)
    page.uncheck("#hide-edited")


def test_bulk_edit_reports_a_conflict_and_keeps_the_rest(browser, review, request,
                                                         tmp_path) -> None:
    """Ctrl-click Row C's three segments and the one-way road E0; someone else edits C1
    meanwhile. Making them 2-lane backward one-ways saves C0 and C2, names C1 (412, Reload
    offered) and E0 (422: it has no backward lane). After Reload, and E0 ctrl-clicked out of
    the selection, applying again saves C1 on top of the other edit."""
    page = open_review(browser, review, request, tmp_path)
    page.fill("#token", review["token"])
    c_ids, (e_id,) = review["ids"]["C"], review["ids"]["E"]
    page.keyboard.down("Control")
    for k in range(3):
        click_lonlat(page, *middle(row_segment(0.0008, k)))
    click_lonlat(page, *middle(E_ONEWAY))
    page.keyboard.up("Control")
    page.locator("#bulk").wait_for(state="visible")
    assert page.locator("#bulk-title").inner_text().startswith("4 segments selected")
    url = f"{review['base']}/collections/webrev-segments/items/{c_ids[1]}"
    meanwhile = httpx.patch(url, json={"name": "Renamed meanwhile"},
                            headers={"Authorization": f"Bearer {review['token']}",
                                     "If-Match": httpx.get(url).headers["ETag"]})
    assert meanwhile.status_code == 200, meanwhile.text

    page.fill("#b-lanes_forward", "2")
    page.select_option("#b-oneway", "backward")
    page.click("#bulk-apply")
    page.wait_for_function("document.querySelector('#bulk-message').textContent"
                           ".startsWith('Saved 2 of 4')")
    message = page.locator("#bulk-message").inner_text()
    assert f"segment {c_ids[1]} changed since you selected it" in message
    assert f"Segment {e_id}: lanes_backward a backward one-way road needs at least one " \
        "backward lane" in message
    marks = {fid: page.locator(f"#bulk-list li[data-segment='{fid}']").get_attribute("class")
             for fid in (*c_ids, e_id)}
    assert marks == {c_ids[0]: "ok", c_ids[1]: "conflict", c_ids[2]: "ok", e_id: "error"}
    assert stored([e_id])[e_id][0] == 1
    assert stored(c_ids) == {c_ids[0]: (2, None, "unclassified", 2, "C0"),
                             c_ids[1]: (2, None, "unclassified", 1, "Renamed meanwhile"),
                             c_ids[2]: (2, None, "unclassified", 2, "C2")}
    page.click("#bulk-reload")
    page.wait_for_function("document.querySelector('#bulk-message').textContent"
                           ".startsWith('Reloaded segment')")
    page.keyboard.down("Control")
    click_lonlat(page, *middle(E_ONEWAY))
    page.keyboard.up("Control")
    assert page.locator("#bulk-title").inner_text().startswith("3 segments selected")
    page.click("#bulk-apply")
    page.wait_for_function("document.querySelector('#bulk-message').textContent"
                           ".startsWith('Saved 3 of 3')")
    assert stored([c_ids[1]])[c_ids[1]] == (3, None, "unclassified", 2, "Renamed meanwhile")
    assert history_rows([c_ids[1]]) == [(c_ids[1], "update", 1, 2), (c_ids[1], "update", 2, 3)]
    # The two saved the first time were already at 2 lanes: no empty versions were written.
    assert stored([c_ids[0]])[c_ids[0]][0] == 2


def test_bulk_delete_of_a_box_selection(browser, review, request, tmp_path) -> None:
    """Box-select the two eastern links of the D chain and delete them: both go with their
    own history rows, the nodes they orphan go too, the map stops drawing them."""
    from sqlalchemy import text

    from app.db.session import session_scope
    from cli.ops.network_integrity import check_network

    page = open_review(browser, review, request, tmp_path)
    page.fill("#token", review["token"])
    d_ids = review["ids"]["D"]
    box_select(page, rv(0.0007, 0.0011), rv(0.0017, 0.0013))
    page.locator("#bulk").wait_for(state="visible")
    assert sorted(page.evaluate("window.ugvmap.selection.list().map((s) => s.id)")) == \
        d_ids[1:]
    page.click("#bulk-delete")
    assert "Delete 2 segments" in page.locator("#bulk-confirm").inner_text()
    page.click("#bulk-delete-yes")
    page.wait_for_function("document.querySelector('#bulk-message').textContent"
                           ".startsWith('Deleted 2 of 2')")
    assert set(stored(d_ids)) == {d_ids[0]}
    assert sorted(history_rows(d_ids)) == [(fid, "delete", 1, None) for fid in d_ids[1:]]
    with session_scope() as s:
        nodes = s.execute(text(
            "SELECT kind FROM road_nodes WHERE network_id = (SELECT id FROM networks "
            "WHERE name = 'webrev') AND ST_DWithin(geom, ST_MakeEnvelope(:w, :s, :e, :n, "
            "4326), 0)"), dict(zip("wsen", (*rv(-0.0001, 0.0011), *rv(0.0016, 0.0013)),
                                   strict=True))).scalars().all()
        assert sorted(nodes) == ["endpoint", "endpoint"]
        assert check_network(s, "webrev").ok
    page.wait_for_function("(ids) => !window.ugvmap.map.queryRenderedFeatures("
                           "{layers: ['net-webrev-segments']}).some((f) => ids.includes(f.id))",
                           arg=d_ids[1:])


def test_route_follows_the_network_on_screen_and_names_the_pieces(browser, review, request,
                                                                  tmp_path) -> None:
    """With several networks the route tool uses the one on screen; a route to a road that
    joins nothing says, in the server's words, which piece each numbered point is on. The
    unclassified island is drawn white over the imagery (it used to be a faint slate)."""
    page = open_map(browser, review, request, tmp_path)
    assert page.locator("#route-network").input_value() == "webnet"
    page.evaluate("(b) => window.ugvmap.map.fitBounds(b, {padding: 20, duration: 0})",
                  list(REVIEW_BOUNDS))
    wait_idle(page)
    assert page.locator("#route-network").input_value() == "webrev"
    page.evaluate("(b) => window.ugvmap.map.fitBounds(b, {padding: 30, duration: 0})",
                  list(RASTER_BOUNDS))
    wait_idle(page)
    assert page.locator("#route-network").input_value() == "webnet"
    assert close(pixel(page, *middle(ISLAND)), (255, 255, 255), tolerance=12)

    page.check("#route-active")
    click_lonlat(page, *at(0.0005, 0))
    click_lonlat(page, *middle(ISLAND))
    error = page.locator("#route-result .route-error")
    error.wait_for()
    assert re.fullmatch(r"No route from point 1 to point 2: point 1 is on a piece of the "
                        r"network of 4 segments \(\d+ m\) and point 2 on another of 1 segment "
                        r"\(\d+ m\): no road joins them\.", error.inner_text()), \
        error.inner_text()


def test_route_names_its_network_and_vehicle_and_zoom_picks_the_network(browser, review, request,
                                                                        tmp_path) -> None:
    """The route tool says which network it routes on, why, and for which vehicle; *Zoom* on a
    network picks it, and the pick holds when the map moves over another network (it used to
    follow the map centre and route on whatever lay there)."""
    page = open_map(browser, review, request, tmp_path)
    on = page.locator("#route-on")
    assert on.inner_text() == ("Routing on webnet (the network under the map centre; pick "
                               "another above) for a car.")
    assert page.locator("#route-profile").input_value() == "car"
    options = page.locator("#route-profile option").all_inner_texts()
    assert options == ["car", "sidewalk"]
    page.locator('#networks li[data-network="webrev"] button.zoom').click()
    wait_idle(page)
    assert page.locator("#route-network").input_value() == "webrev"
    assert on.inner_text() == "Routing on webrev (picked) for a car."
    page.evaluate("(b) => window.ugvmap.map.fitBounds(b, {padding: 30, duration: 0})",
                  list(RASTER_BOUNDS))
    wait_idle(page)
    assert page.locator("#route-network").input_value() == "webrev"
    page.select_option("#route-profile", "sidewalk")
    assert on.inner_text() == "Routing on webrev (picked) for a sidewalk."
    # The route request carries the vehicle.
    page.select_option("#route-network", "webnet")
    page.check("#route-active")
    with page.expect_request(lambda r: "/networks/webnet/route?" in r.url) as sent:
        click_lonlat(page, *at(0.0002, 0))
        click_lonlat(page, *at(0.0018, 0))
    assert "profile=sidewalk" in sent.value.url
    page.locator("#route-result .distance").wait_for()


def test_one_point_off_the_road_keeps_the_legs_that_work(browser, world, request,
                                                         tmp_path) -> None:
    """Five points, the third far from every road: the legs 1→2 and 4→5 are drawn, point 3 is
    marked and named, instead of the whole route vanishing behind one error."""
    page = open_map(browser, world, request, tmp_path)
    plan_route(page)
    points = [at(0.0002, 0), at(0.0018, 0), at(0.0024, 0.0017), at(0.001, 0.0015),
              at(0.0005, 0.001)]
    for point in points:
        click_lonlat(page, *point)
    partial = page.locator("#route-result .route-partial")
    partial.wait_for()
    assert partial.inner_text() == "Showing the legs that work: 1→2, 4→5."
    errors = page.locator("#route-result .route-error").all_inner_texts()
    assert len(errors) == 1 and errors[0].startswith("No route: point 3 ("), errors
    assert "farther than 50 m from any road" in errors[0]
    marked = page.evaluate("() => [...document.querySelectorAll('.task-point')]"
                           ".map((el) => el.classList.contains('off-road'))")
    assert marked == [False, False, True, False, False]
    lines = page.evaluate("() => window.ugvmap.map.getSource('route').serialize().data"
                          ".features.length")
    assert lines == 2
    assert route_distance_m(page) > 100
    # Move the bad point onto a road: the whole route is back, nothing marked.
    page.locator(".task-point").nth(2).click()
    page.wait_for_function("() => !document.querySelector('.task-point.off-road')")
    page.locator("#route-result .distance").wait_for()
    page.wait_for_function("() => !document.querySelector('#route-result .route-partial')")


def test_inspector_says_which_vehicle_may_drive_a_segment(browser, review, request,
                                                          tmp_path) -> None:
    """Every way is kept (an OSM import keeps footways): the inspector says which vehicle
    profile may drive the segment, from its class and the server's profiles."""
    from sqlalchemy import text

    from app.db.session import session_scope

    page = open_review(browser, review, request, tmp_path)
    segment = review["ids"]["E"][0]
    click_lonlat(page, *middle(E_ONEWAY))
    vehicles = page.locator('#seg-readonly dd[data-field="vehicles"]')
    page.wait_for_function("document.querySelector('#f-name').value === 'E0'")
    assert vehicles.inner_text() == "car, sidewalk"
    with session_scope() as s:
        s.execute(text("UPDATE road_segments SET road_class = 'footway' WHERE id = :id"),
                  {"id": segment})
    try:
        page.evaluate("(id) => window.ugvmap.inspector.open('webrev', id)", segment)
        page.wait_for_function("document.querySelector('#f-road_class').value === 'footway'")
        assert vehicles.inner_text() == "sidewalk (never car)"
    finally:
        with session_scope() as s:
            s.execute(text("UPDATE road_segments SET road_class = 'unclassified' WHERE id = :id"),
                      {"id": segment})
