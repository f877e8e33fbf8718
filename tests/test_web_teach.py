"""The web map's Teach tool in real headless Chromium against the real server and its own
queue worker: Preview shows the view's roads dashed magenta with their counts, Accept puts
them into the chosen network, which redraws."""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import text

from app.db.session import get_engine, session_scope
from ingest.raster.job import ingest_raster
from ingest.roads.layer import ingest_layer_roads
from ingest.roads.pipeline import ExtractParams
from testkit.network_helpers import token
from testkit.server import running_server
from tests.test_road_previews import write_scene
from tests.test_web_map import finish, screen, wait_idle

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def teach_world(module_database: str, tmp_path_factory: pytest.TempPathFactory
                ) -> Iterator[dict]:
    """The synthetic scene as layer ``teach``, network ``teach-net`` extracted from it, and the
    server with one queue worker beside it (as ``ugvmap serve`` starts by default)."""
    folder = tmp_path_factory.mktemp("web-teach")
    bbox = write_scene(folder / "scene.tif")
    ingest_raster([folder / "scene.tif"], "teach")
    with session_scope() as session:
        ingest_layer_roads(session, "teach", "teach-net", None, ExtractParams())
    env = {"DATABASE_URL": module_database,
           "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"]}
    with running_server(env, queue_workers=1, timeout_s=120) as base:
        yield {"base": base, "bbox": bbox, "token": token("editor")}


def segment_history_actions() -> dict[str, int]:
    with get_engine().connect() as conn:
        return dict(conn.execute(text(  # type: ignore[arg-type]
            "SELECT action, count(*) FROM segment_edits e JOIN networks n "
            "ON n.id = e.network_id WHERE n.name = 'teach-net' GROUP BY action")).all())


def stored_labels() -> set[tuple[str, str]]:
    with get_engine().connect() as conn:
        return {tuple(r) for r in conn.execute(text(
            "SELECT label, ST_GeometryType(geom) FROM layer_labels"))}


def test_teach_label_preview_then_accept(browser, teach_world, request, tmp_path: Path) -> None:
    context = browser.new_context(viewport={"width": 1100, "height": 750})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    outside: list[str] = []
    page.on("request", lambda r: None if r.url.startswith(teach_world["base"])
            or r.url.startswith(("data:", "blob:")) else outside.append(r.url))
    request.addfinalizer(lambda: finish(page, context, request, tmp_path, errors, outside))
    page.goto(teach_world["base"] + "/")
    page.wait_for_selector("body[data-ready=true]", timeout=20_000)
    page.evaluate("(b) => window.ugvmap.map.fitBounds(b, {padding: 10, duration: 0})",
                  list(teach_world["bbox"]))
    wait_idle(page)
    page.fill("#token", teach_world["token"])
    page.select_option("#teach-layer", "teach")
    page.select_option("#teach-network", "teach-net")
    assert page.locator("#teach-accept").is_disabled()

    # Label: a road line along the T arm (two clicks, a double-click ends it) and a not-road
    # box in an empty corner; both stored, drawn and listed; the box removed again.
    page.check("#teach-active")
    page.check("input[name=teach-mode][value=road]")
    x0, y0, x1, y1 = teach_world["bbox"]
    arm_x = x0 + (x1 - x0) * 60 / 400
    for fraction in (0.55, 0.9):
        page.mouse.click(*screen(page, arm_x, y1 - (y1 - y0) * fraction))
    page.mouse.dblclick(*screen(page, arm_x, y1 - (y1 - y0) * 0.9))
    page.wait_for_selector("#teach-labels li", timeout=10_000)
    page.check("input[name=teach-mode][value=not_road_box]")
    page.mouse.click(*screen(page, x0 + (x1 - x0) * 0.7, y0 + (y1 - y0) * 0.1))
    page.mouse.click(*screen(page, x0 + (x1 - x0) * 0.9, y0 + (y1 - y0) * 0.3))
    page.wait_for_function("() => document.querySelectorAll('#teach-labels li').length === 2",
                           timeout=10_000)
    assert stored_labels() == {("road", "ST_LineString"), ("not_road", "ST_Polygon")}
    page.locator("#teach-labels li", has_text="not-road area").locator("button").click()
    page.wait_for_function("() => document.querySelectorAll('#teach-labels li').length === 1",
                           timeout=10_000)
    assert stored_labels() == {("road", "ST_LineString")}
    page.uncheck("#teach-active")

    page.click("#teach-preview")
    page.wait_for_function(
        "() => /roads, confidence mean|failed|No preview/.test("
        "document.getElementById('teach-result').textContent)", timeout=120_000)
    summary = page.locator("#teach-result").inner_text()
    assert "1 road / 0 not-road labels" in summary, summary
    assert re.search(r"\(sample (not )?used: on the held-out half", summary), summary
    wait_idle(page)
    drawn = page.evaluate("() => window.ugvmap.map.queryRenderedFeatures("
                          "{layers: ['teach-preview-line']}).length")
    assert drawn > 0, "the preview's roads are not drawn"
    assert page.evaluate("() => window.ugvmap.map.getPaintProperty('teach-preview-line', "
                         "'line-color')") == "#ff00ff"

    page.click("#teach-accept")
    page.wait_for_function("() => /Accepted into|Not accepted/.test("
                           "document.getElementById('teach-result').textContent)",
                           timeout=30_000)
    result = page.locator("#teach-result").inner_text()
    assert re.match(r"Accepted into teach-net as change set \d+: \d+ added, \d+ moved, "
                    r"\d+ removed, \d+ kept", result), result
    actions = segment_history_actions()
    assert actions.get("accept", 0) > 0 and set(actions) == {"accept"}
    assert page.locator("#teach-accept").is_disabled()
    wait_idle(page)
    assert page.evaluate("() => window.ugvmap.map.queryRenderedFeatures("
                         "{layers: ['teach-preview-line']}).length") == 0
    assert page.evaluate("() => window.ugvmap.map.queryRenderedFeatures("
                         "{layers: ['net-teach-net-segments']}).length") > 0
