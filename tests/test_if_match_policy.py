"""The If-Match policy (``UGVMAP_IF_MATCH``): a stale If-Match is a 412 under either setting;
a write without one is a 428 under ``required`` and, under ``optional`` (the default, for
QGIS), applies to the current version while the history keeps what it overwrote, so the lost
update can be seen and reverted."""

from __future__ import annotations

import pytest

from testkit.network_helpers import bearer, grid_network


@pytest.fixture()
def item(client) -> str:
    net = grid_network()
    items = f"/collections/{net.network}-segments/items"
    return f"{items}/{client.get(items).json()['features'][0]['id']}"


def test_qgis_overwriting_a_web_edit_is_recorded_and_revertable(client, item: str) -> None:
    """The web map saves with If-Match; QGIS, holding the old version, saves without: its
    write goes through over the web map's, and the history shows which version it overwrote
    (``conditional: false``) with that version's values, so a revert brings them back."""
    web = {**bearer("editor"), "If-Match": '"1"'}
    assert client.patch(item, json={"name": "Web name", "speed_limit_kph": 30},
                        headers=web).status_code == 200
    qgis = client.patch(item, json={"properties": {"name": "QGIS name"}},
                        headers={**bearer("editor"),
                                 "Content-Type": "application/merge-patch+json"})
    assert qgis.status_code == 200 and qgis.headers["etag"] == '"3"'
    edits = client.get(f"{item}/history").json()["edits"]
    assert [(e["version_from"], e["version_to"], e["conditional"]) for e in edits] == \
        [(1, 2, True), (2, 3, False)]
    assert edits[1]["old"] == {"name": "Web name"} and edits[1]["new"] == {"name": "QGIS name"}
    # The web map's next save still names its version: stale, so refused and nothing changes.
    stale = client.patch(item, json={"lanes_forward": 2}, headers={**web, "If-Match": '"2"'})
    assert (stale.status_code, stale.json()["code"], stale.headers["etag"]) == \
        (412, "PreconditionFailed", '"3"')
    reverted = client.post(f"{item}/revert", params={"to": 2},
                           headers={**bearer("editor"), "If-Match": '"3"'})
    assert reverted.status_code == 200
    props = reverted.json()["properties"]
    assert (props["name"], props["speed_limit_kph"], props["version"]) == ("Web name", 30, 4)


def test_required_refuses_writes_without_if_match(client, item: str,
                                                  if_match_required) -> None:
    for write in (lambda h: client.patch(item, json={"name": "x"}, headers=h),
                  lambda h: client.put(item, json={"type": "Feature", "geometry": client.get(
                      item).json()["geometry"], "properties": {}}, headers=h),
                  lambda h: client.delete(item, headers=h)):
        r = write(bearer("editor"))
        assert (r.status_code, r.json()["code"]) == (428, "PreconditionRequired")
        assert write({**bearer("editor"), "If-Match": '"9"'}).status_code == 412
    assert client.get(item).json()["properties"]["version"] == 1
    assert client.get(f"{item}/history").json()["edits"] == []
    # ``If-Match: *`` (RFC 9110: any current version) is an explicit choice: accepted.
    r = client.patch(item, json={"name": "any"}, headers={**bearer("editor"), "If-Match": "*"})
    assert r.status_code == 200
    assert client.get(f"{item}/history").json()["edits"][0]["conditional"] is False


@pytest.mark.parametrize("policy", ["optional", "required"])
def test_stale_if_match_is_412_whatever_the_policy(client, item: str, policy: str,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    from app.settings import get_settings

    monkeypatch.setenv("UGVMAP_IF_MATCH", policy)
    get_settings.cache_clear()
    try:
        r = client.delete(item, headers={**bearer("editor"), "If-Match": '"2"'})
        assert (r.status_code, r.headers["etag"]) == (412, '"1"')
    finally:
        monkeypatch.delenv("UGVMAP_IF_MATCH")
        get_settings.cache_clear()
    assert client.get(item).status_code == 200
