"""``ugvmap network delete``: everything of the network goes, other networks stay, and every
worker's MVT cache and routing graph forget it (NOTIFY)."""

from __future__ import annotations

import time

from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import session_scope
from app.network.tile_cache import shared_cache
from app.routing.live import registry
from app.settings import get_settings
from cli.main import main
from testkit.network_helpers import NoteWatch, bearer, grid_network


def _cli(*args: str, stdin: str | None = None):
    result = CliRunner().invoke(main, list(args), input=stdin)
    return result.exit_code, result.output


def _rows(network_id: int) -> tuple[int, ...]:
    with session_scope() as s:
        return tuple(s.execute(text(f"SELECT count(*) FROM {t} WHERE network_id = :n"),
                               {"n": network_id}).scalar_one()
                     for t in ("road_segments", "road_nodes", "segment_edits"))


def _network_version(network_id: int) -> int:
    with session_scope() as s:
        return s.execute(text("SELECT version FROM networks WHERE id = :n"),
                         {"n": network_id}).scalar_one()


def _wait_for(condition, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def test_delete_network_and_forget_it_everywhere(client) -> None:
    doomed, kept = grid_network(), grid_network()
    items = f"/collections/{doomed.network}-segments/items"
    fid = client.get(items).json()["features"][0]["id"]
    cache = shared_cache(get_settings().database_url)  # subscribed before the note below
    notes = NoteWatch(get_settings().database_url, doomed.network_id)
    assert client.patch(f"{items}/{fid}", json={"name": "x"},
                        headers={**bearer("editor"), "If-Match": '"1"'}).status_code == 200
    # The edit's invalidation must land before the tile is cached, or it drops the tile
    # between the two GETs below (a "miss" where a "hit" is expected).
    assert notes.wait_for(_network_version(doomed.network_id)), "the edit's note never came"
    tile = f"/networks/{doomed.network}/tiles/14/8647/5556.mvt"
    assert client.get(tile).status_code == 200
    assert client.get(tile).headers["x-tile-cache"] == "hit"
    route = client.get(f"/networks/{doomed.network}/route",
                       params={"points": "10.0,50.0;10.002,50.002"})
    assert route.status_code == 200, route.text
    graphs = registry(get_settings().database_url)
    assert doomed.network_id in graphs._graphs
    assert any(k[0] == doomed.network_id for k in cache._tiles)

    code, out = _cli("network", "delete", doomed.network, stdin="n\n")
    assert code == 1 and "Aborted" in out and _rows(doomed.network_id) == (12, 9, 1)
    code, out = _cli("network", "delete", doomed.network, "--yes")
    assert code == 0, out
    assert f"deleted network {doomed.network}: 12 segments, 9 nodes, 1 history" in out
    assert _rows(doomed.network_id) == (0, 0, 0)
    assert _rows(kept.network_id)[:2] == (12, 9)
    assert _wait_for(lambda: doomed.network_id not in graphs._graphs)
    assert _wait_for(lambda: not any(k[0] == doomed.network_id for k in cache._tiles))
    for url in (tile, items, f"/collections/{doomed.network}-segments"):
        assert client.get(url).status_code == 404, url
    assert client.get(f"/collections/{kept.network}-segments/items").status_code == 200


def test_delete_refuses_unknown_and_invalid_names(database_url: str) -> None:
    code, out = _cli("network", "delete", "no-such-network", "--yes")
    assert code == 1 and "network 'no-such-network' does not exist" in out
    code, out = _cli("network", "delete", "Bad\x00Name", "--yes")
    assert code == 1 and "network name" in out and "Traceback" not in out
