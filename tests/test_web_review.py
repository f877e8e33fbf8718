"""The web map's review of a re-survey in real headless Chromium against the real server: a
change set of the grid (two roads moved, one missing, one new) drawn in its own style, one
proposal picked on the map and accepted, the rest rejected in the view, the set reverted."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from testkit.network_helpers import grid_network, token
from testkit.server import running_server
from tests.test_resurvey_changes import rows, survey, update
from tests.test_web_map import finish, screen, wait_idle

pytestmark = pytest.mark.slow

GRID = [10.0, 50.0, 10.002, 50.0028]  # the grid and the new road north of it


@pytest.fixture(scope="module")
def review_world(module_database: str, tmp_path_factory: pytest.TempPathFactory
                 ) -> Iterator[dict]:
    """The grid network and a change set of it, served."""
    name = grid_network().network
    set_id = update(survey(tmp_path_factory.mktemp("review") / "survey.geojson"), name)
    env = {"DATABASE_URL": module_database,
           "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"]}
    with running_server(env) as base:
        yield {"base": base, "name": name, "set": set_id, "token": token("editor")}


def result_text(page, pattern: str) -> str:
    page.wait_for_function(f"() => /{pattern}/.test("
                           "document.getElementById('review-result').textContent)",
                           timeout=20_000)
    return page.locator("#review-result").inner_text()


def drawn_kinds(page) -> dict[str, int]:
    return page.evaluate(
        "() => { const out = {}; for (const f of window.ugvmap.map.queryRenderedFeatures("
        "{layers: ['review-missing', 'review-moved-new']})) { if (f.properties.status === "
        "'proposed') out[f.properties.kind] = (out[f.properties.kind] || 0) + 1; } "
        "return out; }")


def statuses(set_id: int) -> dict[str, str]:
    return {f"{r.kind}:{r.segment_id or 'new'}": r.status for r in rows(
        "SELECT kind, segment_id, status FROM proposed_changes WHERE change_set_id = :s",
        s=set_id)}


def test_review_a_change_set_on_the_map(browser, review_world, request, tmp_path: Path
                                        ) -> None:
    context = browser.new_context(viewport={"width": 1100, "height": 900})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    outside: list[str] = []
    page.on("request", lambda r: None if r.url.startswith(review_world["base"])
            or r.url.startswith(("data:", "blob:")) else outside.append(r.url))
    request.addfinalizer(lambda: finish(page, context, request, tmp_path, errors, outside))
    page.goto(review_world["base"] + "/")
    page.wait_for_selector("body[data-ready=true]", timeout=20_000)
    page.evaluate("(b) => window.ugvmap.map.fitBounds(b, {padding: 60, duration: 0})", GRID)
    page.fill("#token", review_world["token"])
    page.select_option("#review-network", review_world["name"])
    page.check("#review-active")
    assert "4 proposals to review" in result_text(page, "proposals to review")
    wait_idle(page)
    # Each kind drawn in its own style over the map, proposals only (nothing decided yet).
    assert drawn_kinds(page).keys() == {"moved", "new", "missing"}
    colours = page.evaluate("() => window.ugvmap.map.getPaintProperty('review-moved-new', "
                            "'line-color')")
    assert colours[:6] == ["match", ["get", "kind"], "moved", "#ff9f1c", "new", "#00d5ff"]

    # Pick the new road on the map and accept it alone: it joins the network.
    page.mouse.click(*screen(page, 10.0005, 50.0023))
    assert "new road" in page.locator("#review-picked").inner_text()
    page.click("#review-accept-picked")
    assert "1 accepted" in result_text(page, "Accepted|Not accepted")
    assert statuses(review_world["set"])["new:new"] == "accepted"
    assert rows("SELECT count(*) AS n FROM segment_edits WHERE action = 'resurvey' AND "
                "(new->>'change_set')::bigint = :s", s=review_world["set"])[0].n == 1

    page.click("#review-reject-view")  # the view shows the whole grid: the other three
    assert "3 rejected" in result_text(page, "Rejected|Not rejected")
    assert set(statuses(review_world["set"]).values()) == {"accepted", "rejected"}
    wait_idle(page)
    assert drawn_kinds(page) == {}

    page.click("#review-revert")
    assert "1 changes undone" in result_text(page, "Reverted|Not reverted")
    assert set(statuses(review_world["set"]).values()) == {"reverted", "rejected"}
    assert "reverted" in page.locator("#review-set option").first.inner_text()
