"""Authenticated attribute editing: auth, optimistic concurrency, validation, history, revert."""

from __future__ import annotations

import threading

import httpx
import pytest
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from testkit.network_helpers import bearer, grid_network


@pytest.fixture()
def segment(database_url: str, client) -> tuple[str, int]:
    """(items URL, id) of one segment of a fresh grid network."""
    net = grid_network()
    url = f"/collections/{net.network}-segments/items"
    fid = client.get(url, params={"limit": 1}).json()["features"][0]["id"]
    return url, fid


def _state(client, url: str, fid: int) -> dict:
    response = client.get(f"{url}/{fid}")
    assert response.status_code == 200
    assert response.headers["etag"] == f'"{response.json()["properties"]["version"]}"'
    return response.json()["properties"]


def _edits(fid: int) -> int:
    with session_scope() as s:
        return s.execute(text("SELECT count(*) FROM segment_edits WHERE segment_id = :s"),
                         {"s": fid}).scalar_one()


def test_auth_is_required_and_role_checked(client, segment) -> None:
    url, fid = segment
    before = _state(client, url, fid)
    patch = {"speed_limit_kph": 30}
    cases = [({}, 401), ({"Authorization": "Bearer nope"}, 401),
             ({"Authorization": "Basic YWxpY2U6eA=="}, 401), (bearer("viewer"), 403)]
    for headers, status in cases:
        r = client.patch(f"{url}/{fid}", json=patch, headers={**headers, "If-Match": '"1"'})
        assert r.status_code == status, r.text
        assert r.json()["code"] in ("Unauthorized", "Forbidden")
    assert _state(client, url, fid) == before and _edits(fid) == 0


def test_if_match_required_and_stale_version_refused(client, segment,
                                                      if_match_required) -> None:
    url, fid = segment
    auth = bearer("editor")
    before = _state(client, url, fid)
    assert client.patch(f"{url}/{fid}", json={"lanes_forward": 1},
                        headers=auth).status_code == 428
    stale = client.patch(f"{url}/{fid}", json={"lanes_forward": 1},
                         headers={**auth, "If-Match": '"7"'})
    assert stale.status_code == 412 and stale.headers["etag"] == '"1"'
    assert _state(client, url, fid) == before and _edits(fid) == 0


def test_bad_values_get_a_message_per_field_and_change_nothing(client, segment) -> None:
    url, fid = segment
    before = _state(client, url, fid)
    bad = {"lanes_forward": 9, "lanes_backward": -1, "speed_limit_kph": 400, "oneway": "up",
           "road_class": "spaceship", "name": "x" * 201, "width_m": "wide",
           "is_junction": "yes", "length_m": 1, "colour": "red", "oneway_typo": 1,
           "surface": "a\x00b"}
    r = client.patch(f"{url}/{fid}", json=bad, headers={**bearer("editor"), "If-Match": '"1"'})
    assert r.status_code == 422
    body = r.json()
    assert body["code"] == "InvalidValue"
    assert set(body["errors"]) == set(bad)
    assert "0 to 8" in body["errors"]["lanes_forward"]
    assert "5 to 150" in body["errors"]["speed_limit_kph"]
    assert "read-only" in body["errors"]["length_m"]
    # One good field among bad ones is not applied either.
    r = client.patch(f"{url}/{fid}", json={"name": "ok", "lanes_forward": 99},
                     headers={**bearer("editor"), "If-Match": '"1"'})
    assert r.status_code == 422 and set(r.json()["errors"]) == {"lanes_forward"}
    assert _state(client, url, fid) == before and _edits(fid) == 0


def test_good_edit_bumps_version_writes_history_and_reverts(client, segment) -> None:
    url, fid = segment
    headers = {**bearer("editor"), "Content-Type": "application/merge-patch+json"}
    r = client.patch(f"{url}/{fid}", content='{"speed_limit_kph": 30, "attrs": {"lit": "yes"},'
                     '"name": "Main St"}', headers={**headers, "If-Match": '"1"'})
    assert r.status_code == 200, r.text
    assert r.headers["etag"] == '"2"'
    props = _state(client, url, fid)
    assert (props["version"], props["speed_limit_kph"], props["name"]) == (2, 30, "Main St")
    assert props["attrs"] == {"lit": "yes"} and props["updated_by"].startswith("editor-")
    # Merge patch on attrs: null removes a key, other keys stay.
    r = client.patch(f"{url}/{fid}", json={"properties": {"attrs": {"lit": None, "x": 1}}},
                     headers={**bearer("admin"), "If-Match": '"2"'})
    assert r.status_code == 200 and r.json()["properties"]["attrs"] == {"x": 1}
    edits = client.get(f"{url}/{fid}/history").json()["edits"]
    assert [(e["version_from"], e["version_to"]) for e in edits] == [(1, 2), (2, 3)]
    assert edits[0]["old"]["speed_limit_kph"] == 50.0 and edits[0]["old"]["attrs"] == {}
    assert edits[0]["new"]["name"] == "Main St"
    r = client.post(f"{url}/{fid}/revert", params={"to": 1},
                    headers={**bearer("editor"), "If-Match": '"3"'})
    assert r.status_code == 200, r.text
    props = _state(client, url, fid)
    assert props["version"] == 4 and props["speed_limit_kph"] == 50 and props["attrs"] == {}
    assert client.get(f"{url}/{fid}/history").json()["edits"][-1]["action"] == "revert"
    assert client.post(f"{url}/{fid}/revert", params={"to": 9},
                       headers={**bearer("editor"), "If-Match": '"4"'}).status_code == 422


def test_geometry_edit_must_keep_its_nodes(client, segment) -> None:
    url, fid = segment
    feature = client.get(f"{url}/{fid}").json()
    coords = feature["geometry"]["coordinates"]
    # The start is 5e-8 degrees off its node: accepted and snapped onto it.
    bent = [[coords[0][0] + 5e-8, coords[0][1]],
            [(coords[0][0] + coords[-1][0]) / 2, coords[0][1] + 0.0002], coords[-1]]
    auth = {**bearer("editor"), "If-Match": '"1"'}
    moved = [[coords[0][0] + 0.01, coords[0][1]], coords[-1]]
    r = client.patch(f"{url}/{fid}", json={"geometry": {"type": "LineString",
                                                        "coordinates": moved}}, headers=auth)
    assert r.status_code == 422 and "nodes" in r.json()["errors"]["geometry"]
    r = client.patch(f"{url}/{fid}", json={"geometry": {"type": "LineString",
                                                        "coordinates": bent}}, headers=auth)
    assert r.status_code == 200
    assert r.json()["properties"]["length_m"] > feature["properties"]["length_m"]
    assert r.json()["geometry"]["coordinates"][0] == coords[0]
    network = url.split("/")[2].removesuffix("-segments")
    assert CliRunner().invoke(main, ["network", "validate", network]).exit_code == 0


@pytest.mark.slow
def test_concurrent_patches_one_winner_per_version(live_server: str) -> None:
    net = grid_network()
    url = f"{live_server}/collections/{net.network}-segments/items"
    fid = httpx.get(url, params={"limit": 1}).json()["features"][0]["id"]
    auth = bearer("editor")
    clients = 20
    wins: dict[int, int] = {}
    first_try: dict[int, int] = {}
    barrier = threading.Barrier(clients)

    def editor(i: int) -> None:
        with httpx.Client(timeout=30) as http:
            version = 1
            barrier.wait()
            while True:
                r = http.patch(f"{url}/{fid}", json={"name": f"client {i}"},
                               headers={**auth, "If-Match": f'"{version}"'})
                first_try.setdefault(i, r.status_code)
                if r.status_code == 200:
                    wins[i] = int(r.headers["etag"].strip('"'))
                    return
                assert r.status_code == 412, r.text
                version = int(r.headers["etag"].strip('"'))

    threads = [threading.Thread(target=editor, args=(i,)) for i in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    # All 20 first tries carried If-Match "1": exactly one of them won.
    assert sorted(first_try.values()) == [200] + [412] * (clients - 1)
    # Retrying with the fresh ETag, each client won exactly once, one winner per version.
    assert sorted(wins.values()) == list(range(2, clients + 2))
    edits = httpx.get(f"{url}/{fid}/history").json()["edits"]
    assert [(e["version_from"], e["version_to"]) for e in edits] == \
        [(v, v + 1) for v in range(1, clients + 1)]
    assert {e["new"]["name"] for e in edits} == {f"client {i}" for i in range(clients)}
    final = httpx.get(f"{url}/{fid}").json()["properties"]
    assert final["version"] == clients + 1 and final["name"] == edits[-1]["new"]["name"]


def test_cli_token_is_shown_once_and_stored_hashed(client, segment) -> None:
    result = CliRunner().invoke(main, ["tokens", "create", "--role", "editor", "--name", "bob"])
    assert result.exit_code == 0, result.output
    token = result.output.strip()
    with session_scope() as s:
        stored = s.execute(text("SELECT token_hash FROM api_tokens WHERE name = 'bob'")).all()
        leaked = s.execute(text("SELECT count(*) FROM api_tokens WHERE token_hash = :t"),
                           {"t": token}).scalar_one()
    assert len(stored) == 1 and stored[0][0] != token and leaked == 0
    url, fid = segment
    r = client.patch(f"{url}/{fid}", json={"surface": "gravel"},
                     headers={"Authorization": f"Bearer {token}", "If-Match": '"1"'})
    assert r.status_code == 200 and r.json()["properties"]["updated_by"] == "bob"
    bad = CliRunner().invoke(main, ["tokens", "create", "--role", "root", "--name", "x"])
    assert bad.exit_code == 2
