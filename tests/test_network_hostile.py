"""Hostile input: SQL metacharacters and huge strings in every parameter and attribute are
stored verbatim or refused with a 4xx; never executed, never a 500, nothing else changes."""

from __future__ import annotations

import json
from urllib.parse import quote

import pytest
from sqlalchemy import text

from app.db.session import session_scope
from testkit.network_helpers import bearer, grid_network

NASTY = [
    "'; DROP TABLE road_segments; --",
    "\" OR 1=1 --",
    "1 UNION SELECT token_hash FROM api_tokens",
    "$$; SELECT pg_sleep(5); $$",
    "%27%3B%00",
    "../../../etc/passwd",
    "Robert'); DELETE FROM networks;--" * 3,
    "x" * 20_000,
]
BODY_ONLY = ["a\x00b", "\udc00 lone surrogate", "ünïcödé ✓ 😀"]


def _counts() -> tuple[int, ...]:
    with session_scope() as s:
        return tuple(s.execute(text(f"SELECT count(*) FROM {t}")).scalar_one()
                     for t in ("networks", "road_segments", "road_nodes", "api_tokens"))


@pytest.fixture(scope="module")
def net(database_url: str):
    return grid_network()


def test_query_and_path_parameters(client, net) -> None:
    fid = client.get(f"/collections/{net.network}-segments/items").json()["features"][0]["id"]
    editor = bearer("editor")
    before = _counts()
    items = f"/collections/{net.network}-segments/items"
    for value in NASTY:
        q = quote(value, safe="")
        urls = [f"/collections/{q}", f"/collections/{q}/items", f"{items}/{q}",
                f"{items}/{q}/history", f"/networks/{q}/tiles/1/0/0.mvt",
                f"/networks/{net.network}/tiles/{q}/0/0.mvt",
                f"/networks/{net.network}/tiles/1/{q}/0.mvt"]
        urls += [f"{items}?{param}={q}" for param in ("bbox", "limit", "offset", "bbox-crs", q)]
        for url in urls:
            r = client.get(url)
            assert 400 <= r.status_code < 500, (url[:120], r.status_code)
            if "%2F" not in q:  # an encoded "/" matches no route at all: the router's 404
                assert set(r.json()) >= {"code", "message"}, url[:120]
        r = client.post(f"{items}/{fid}/revert?to={q}", headers=editor)
        assert r.status_code == 400
        r = client.patch(f"{items}/{fid}", json={"name": "x"},
                         headers={**editor, "If-Match": value[:1000]})
        assert r.status_code == 412
        r = client.patch(f"{items}/{fid}", json={"name": "x"},
                         headers={"Authorization": f"Bearer {value[:1000]}", "If-Match": '"1"'})
        assert r.status_code == 401
    assert _counts() == before
    assert client.get(f"{items}/{fid}").json()["properties"]["version"] == 1


def test_attribute_values_stored_verbatim_or_refused(client, net) -> None:
    items = f"/collections/{net.network}-segments/items"
    fid = client.get(items).json()["features"][1]["id"]
    auth = bearer("editor")
    before = _counts()
    for value in NASTY + BODY_ONLY:
        for key in ("name", "surface", "external_id", "road_class", "oneway", "attrs"):
            version = client.get(f"{items}/{fid}").json()["properties"]["version"]
            patch = {key: {value: value} if key == "attrs" else value}
            r = client.patch(f"{items}/{fid}", content=json.dumps(patch),  # \u escapes
                             headers={**auth, "If-Match": f'"{version}"',
                                      "Content-Type": "application/json"})
            assert r.status_code in (200, 422), (key, value[:40], r.status_code)
            stored = client.get(f"{items}/{fid}").json()["properties"]
            if r.status_code == 200 and key == "attrs":  # merge patch: the key is added
                assert stored["attrs"][value] == value
            elif r.status_code == 200:
                assert stored[key] == value
            else:
                assert stored["version"] == version and key in r.json()["errors"]
    assert _counts() == before
    # The classic injection was stored as plain text, not run.
    r = client.patch(f"{items}/{fid}", json={"name": NASTY[0]},
                     headers={**auth, "If-Match": f'"{stored["version"]}"'})
    assert r.status_code == 200
    assert client.get(f"{items}/{fid}").json()["properties"]["name"] == NASTY[0]


def test_bodies_that_are_not_patches(client, net) -> None:
    items = f"/collections/{net.network}-segments/items"
    fid = client.get(items).json()["features"][2]["id"]
    auth = {**bearer("editor"), "If-Match": '"1"'}
    cases = [("not json", "application/json", 400), ("[1, 2]", "application/json", 422),
             ('{"name": "x"}', "text/plain", 415), ("[" * 100_000, "application/json", 400),
             ('{"properties": "x"}', "application/json", 422),
             ('{"geometry": {"type": "Point", "coordinates": [0, 0]}}', "application/json", 422),
             ('{"speed_limit_kph": NaN}', "application/json", 400),  # NaN is not JSON
             ('{"lanes_forward": 1e400}', "application/json", 422)]
    for body, content_type, status in cases:
        r = client.patch(f"{items}/{fid}", content=body,
                         headers={**auth, "Content-Type": content_type})
        assert r.status_code == status, (body[:40], r.text[:200])
    assert client.get(f"{items}/{fid}").json()["properties"]["version"] == 1
