"""API token lifecycle (issue 12): create with an expiry, list, revoke; ``last_used_at``
written (throttled); a revoked or expired token is refused at once by every worker, and the
read role guards every read of network data."""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from datetime import timedelta

import httpx
import pytest
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import session_scope
from app.errors import UserError
from app.network.tokens import TOUCH_EVERY_S, parse_duration
from app.routing.options import SERVICES
from app.settings import get_settings
from cli.main import main
from testkit.network_helpers import grid_network
from testkit.server import running_server
from tests.conftest import REPO


def _cli(*args: str):
    result = CliRunner().invoke(main, list(args))
    return result.exit_code, result.output


def _create(role: str, *extra: str) -> tuple[str, str]:
    name = f"{role}-{uuid.uuid4().hex[:8]}"
    code, out = _cli("tokens", "create", "--role", role, "--name", name, *extra)
    assert code == 0, out
    return name, out.strip()


def _row(name: str):
    with session_scope() as s:
        return s.execute(text("SELECT * FROM api_tokens WHERE name = :n"), {"n": name}).one()


def test_durations() -> None:
    assert parse_duration("30d") == timedelta(days=30)
    assert parse_duration("12h") == timedelta(hours=12)
    assert parse_duration("2w") == timedelta(weeks=2)
    assert parse_duration("90m") == timedelta(minutes=90)
    for bad in ("30", "d", "0d", "-1d", "1.5d", "30 days", "٣d", "9999999d"):
        with pytest.raises(UserError):
            parse_duration(bad)


def test_create_list_revoke(database_url: str) -> None:
    name, token = _create("editor", "--expires", "30d")
    assert token.startswith("ugv_")
    row = _row(name)
    assert timedelta(days=29, hours=23) < row.expires_at - row.created_at <= timedelta(days=30)
    code, out = _cli("tokens", "list")
    line = next(x for x in out.splitlines() if x.endswith(name))
    assert code == 0 and " editor " in line and " active " in line and token not in out
    assert _cli("tokens", "create", "--role", "viewer", "--name", "x",
                "--expires", "soon")[0] == 1
    code, out = _cli("tokens", "revoke", str(row.id))
    assert code == 0 and f"revoked token {row.id} ({name})" in out
    assert " revoked " in next(x for x in _cli("tokens", "list")[1].splitlines()
                                if x.endswith(name))
    code, out = _cli("tokens", "revoke", str(row.id))
    assert code == 1 and "already revoked" in out
    assert _cli("tokens", "revoke", "nobody-has-this-name")[0] == 1
    assert _cli("tokens", "revoke", "99999999999999999999")[0] == 1


def test_revoke_by_name_needs_a_unique_active_name(database_url: str) -> None:
    name = f"twin-{uuid.uuid4().hex[:8]}"
    for _ in range(2):
        assert _cli("tokens", "create", "--role", "viewer", "--name", name)[0] == 0
    code, out = _cli("tokens", "revoke", name)
    assert code == 1 and "2 active tokens" in out
    with session_scope() as s:
        first = s.execute(text("SELECT min(id) FROM api_tokens WHERE name = :n"),
                          {"n": name}).scalar_one()
    assert _cli("tokens", "revoke", str(first))[0] == 0
    assert _cli("tokens", "revoke", name)[0] == 0  # now only one active token has the name


def test_revoked_and_expired_tokens_are_401(client, database_url: str) -> None:
    net = grid_network()
    items = f"/collections/{net.network}-segments/items"
    fid = client.get(items).json()["features"][0]["id"]
    name, token = _create("editor", "--expires", "1h")
    auth = {"Authorization": f"Bearer {token}", "If-Match": '"1"'}
    assert _row(name).last_used_at is None
    r = client.patch(f"{items}/{fid}", json={"name": "a"}, headers=auth)
    assert r.status_code == 200, r.text
    first_use = _row(name).last_used_at
    assert first_use is not None
    # Throttled: a use within TOUCH_EVERY_S does not write again.
    r = client.patch(f"{items}/{fid}", json={"name": "b"}, headers={**auth, "If-Match": '"2"'})
    assert r.status_code == 200 and _row(name).last_used_at == first_use
    with session_scope() as s:  # an hour later
        s.execute(text("UPDATE api_tokens SET expires_at = now() - interval '1 second', "
                       "last_used_at = now() - make_interval(secs => :s) WHERE name = :n"),
                  {"n": name, "s": TOUCH_EVERY_S + 1})
    r = client.patch(f"{items}/{fid}", json={"name": "c"}, headers={**auth, "If-Match": '"3"'})
    assert (r.status_code, r.json()["code"]) == (401, "Unauthorized")
    assert "expired" in r.json()["message"] and r.headers["www-authenticate"]
    name, token = _create("admin")
    auth = {"Authorization": f"Bearer {token}", "If-Match": '"3"'}
    assert client.patch(f"{items}/{fid}", json={"name": "d"}, headers=auth).status_code == 200
    assert _cli("tokens", "revoke", name)[0] == 0
    r = client.patch(f"{items}/{fid}", json={"name": "e"}, headers={**auth, "If-Match": '"4"'})
    assert r.status_code == 401 and "revoked" in r.json()["message"]
    assert client.get(f"{items}/{fid}").json()["properties"]["name"] == "d"


def test_revocation_holds_at_once_in_every_worker(database_url: str) -> None:
    """Two workers, reads behind the viewer role: after ``ugvmap tokens revoke`` (another
    process) returns, no request with the token is served by either worker."""
    net = grid_network()
    name, token = _create("viewer")
    url = f"/collections/{net.network}-segments/items"
    auth = {"Authorization": f"Bearer {token}"}
    env = {"DATABASE_URL": database_url, "UGVMAP_NETWORK_READ_ROLE": "viewer",
           "UGVMAP_RASTER_STORE": os.environ["UGVMAP_RASTER_STORE"]}
    with running_server(env, workers=2) as base:
        # A fresh connection per request, so both workers answer some of them.
        assert {httpx.get(base + url, headers=auth).status_code for _ in range(20)} == {200}
        assert httpx.get(base + url).status_code == 401
        subprocess.run([sys.executable, "-m", "cli", "tokens", "revoke", name], cwd=REPO,
                       env={**os.environ, "DATABASE_URL": database_url}, check=True,
                       capture_output=True)
        assert {httpx.get(base + url, headers=auth).status_code for _ in range(20)} == {401}


# Example values for the path parameters of the network capability's GET routes.
EXAMPLES = {"collection_id": ("{net}-segments", "{net}-nodes"), "name": ("{net}",),
            "fid": ("{fid}",), "z": ("14",), "x": ("8647",), "y": ("5556",)}


def _read_urls(app) -> list[str]:
    """Every GET route that reads network data (features, schemas, history, discovery, vector
    tiles), from the app's own API document, each with example path values: a new read route
    cannot slip past the read role unnoticed. Routing (every OSRM service on both URL
    families, isochrones) needs points on a road and is tested with them in
    ``tests/test_routing_hostile.py``."""
    routing = tuple(f"/{service}" for service in (*SERVICES, "isochrone"))
    urls = []
    for path, operations in app.openapi()["paths"].items():
        if "get" not in operations or not path.startswith(("/collections", "/networks")) \
                or path.endswith(routing) or any(f"{s}/" in path for s in routing):
            continue
        filled = [path]
        for name, values in EXAMPLES.items():
            filled = [url.replace(f"{{{name}}}", v) for url in filled for v in values]
        urls.extend(filled)
    return sorted(set(urls))


def test_read_role_guards_every_read_of_network_data(client, app,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """Every GET route of the network capability is behind the read role."""
    net = grid_network()
    fid = client.get(f"/collections/{net.network}-segments/items").json()["features"][0]["id"]
    templates = _read_urls(app)
    assert "/collections/{net}-segments/items/{fid}/history" in templates
    assert "/networks/{net}/tiles/14/8647/5556.mvt" in templates
    monkeypatch.setenv("UGVMAP_NETWORK_READ_ROLE", "viewer")
    get_settings.cache_clear()
    _, viewer = _create("viewer")
    try:
        for template in templates:
            url = template.format(net=net.network, fid=fid)
            r = client.get(url)
            assert (r.status_code, r.json()["code"]) == (401, "Unauthorized"), url
            # A viewer passes the role check (a nodes id that does not exist may still 404).
            assert client.get(url, headers={"Authorization": f"Bearer {viewer}"}
                              ).status_code not in (401, 403), url
    finally:
        monkeypatch.delenv("UGVMAP_NETWORK_READ_ROLE")
        get_settings.cache_clear()
