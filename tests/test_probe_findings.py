"""What the hostile probe of issue 22 found (911 requests, 0 x 5xx, 19 handled wrongly), each
refused or answered properly now, with nothing stored changed."""

from __future__ import annotations

import logging

import httpx
import pytest
from sqlalchemy.exc import OperationalError

from app.api.errors import database_unavailable
from app.jobs.redact import strip_paths
from testkit.network_helpers import bearer, grid_network
from testkit.server import raw_exchange


@pytest.fixture()
def grid(client):
    net = grid_network()
    return net, f"/collections/{net.network}-segments/items"


@pytest.mark.parametrize("bbox", ["1_0,50,10.002,50.002", "\u0663,50,10.002,50.002",
                                  "-500,50,10.002,50.002", "10,-91,10.002,50.002",
                                  "10, 50,10.002,50.002", "10,50,10.002", "0x1,50,10,50.1"])
def test_bbox_numbers_are_ascii_decimals_within_range(client, grid, bbox: str) -> None:
    """``1_0`` was read as 10 (and made an antimeridian box), Arabic digits as digits, a
    longitude of -500 as a longitude."""
    _, items = grid
    r = client.get(items, params={"bbox": bbox})
    assert (r.status_code, r.json()["code"]) == (400, "InvalidParameterValue"), bbox


def test_a_repeated_query_parameter_is_refused(client, grid) -> None:
    """The last value used to win silently, also on a write (``revert?to=1&to=2``)."""
    _, items = grid
    fid = client.get(items).json()["features"][0]["id"]
    editor = bearer("editor")
    assert client.patch(f"{items}/{fid}", json={"name": "v2"},
                        headers={**editor, "If-Match": '"1"'}).status_code == 200
    for method, url in (("POST", f"{items}/{fid}/revert?to=1&to=2"),
                        ("GET", f"{items}?limit=1&limit=2"),
                        ("GET", f"{items}?bbox=0,0,1,1&bbox=10,50,10.002,50.002"),
                        ("GET", "/jobs?limit=1&limit=2"), ("GET", "/layers?x=1&x=1")):
        r = client.request(method, url, headers={**editor, "If-Match": '"2"'})
        assert (r.status_code, r.json()["code"]) == (400, "InvalidParameterValue"), url
        assert "more than once" in r.json()["message"]
    assert client.get(f"{items}/{fid}").json()["properties"]["name"] == "v2"
    # Routing keeps OSRM's own code for it.
    r = client.get("/networks/x/route/v1/driving/10,50;10.001,50?steps=true&steps=false")
    assert r.json()["code"] == "InvalidQuery"


@pytest.mark.parametrize(("path", "body", "key"), [
    ("split", {"fraction": 0.5, "colour": "red"}, "colour"),
    ("merge", {"segments": [1, 2], "force": True}, "force"),
])
def test_split_and_merge_refuse_unknown_body_keys(client, grid, path, body, key) -> None:
    net, items = grid
    fid = client.get(items).json()["features"][0]["id"]
    url = f"{items}/{fid}/split" if path == "split" else \
        f"/collections/{net.network}-segments/merge"
    r = client.post(url, json=body, headers=bearer("admin"))
    assert (r.status_code, r.json()["code"]) == (422, "InvalidValue")
    assert key in r.json()["errors"]
    assert client.get(items).json()["numberMatched"] == 12


def test_security_headers_on_the_web_map_and_the_api(client) -> None:
    for path in ("/", "/web/app.js", "/collections", "/no/such/path"):
        headers = client.get(path).headers
        assert headers["x-content-type-options"] == "nosniff", path
        assert headers["x-frame-options"] == "DENY", path
        assert headers["content-security-policy"] == "frame-ancestors 'none'", path
        assert headers["referrer-policy"] == "no-referrer", path


def test_another_site_cannot_frame_the_web_map(browser, live_server: str, tmp_path) -> None:
    """Chromium on a page of another origin that puts the web map in an iframe: the frame
    stays empty (where an editor pastes a token, clickjacking must not work)."""
    import threading
    from http.server import HTTPServer, SimpleHTTPRequestHandler

    (tmp_path / "index.html").write_text(f'<iframe id="f" src="{live_server}/"></iframe>')

    class Quiet(SimpleHTTPRequestHandler):
        def __init__(self, *a, **kw) -> None:
            super().__init__(*a, directory=str(tmp_path), **kw)

        def log_message(self, *a) -> None:
            pass

    server = HTTPServer(("127.0.0.1", 0), Quiet)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        page = browser.new_page()
        page.goto(f"http://127.0.0.1:{server.server_port}/index.html")
        page.wait_for_timeout(1500)
        frame = next(f for f in page.frames if f != page.main_frame)
        print("framed:", frame.url)
        assert frame.url.startswith("chrome-error://")  # refused, not the map
        page.close()
    finally:
        server.shutdown()


def test_database_down_answer_names_no_host_or_port(caplog) -> None:
    """The 503 told anonymous clients where the database is; that is the operator's (log)."""
    caplog.set_level(logging.WARNING, logger="app.errors")
    driver = Exception('connection failed: connection to server at "10.1.2.3", port 54329 '
                       "failed: Connection refused\n\tIs the server running on that host?")
    response = database_unavailable(None, OperationalError("SELECT 1", {}, driver))
    body = response.body.decode()
    assert response.status_code == 503 and "Connection refused" in body
    assert "10.1.2.3" not in body and "54329" not in body
    assert "10.1.2.3" in caplog.text and "54329" in caplog.text


def test_job_paths_with_spaces_are_redacted_whole() -> None:
    """Redaction stopped at the first space: "/srv/survey data/x.tif" showed "data/x.tif"."""
    message = "cannot read /srv/survey data/zone a.tif: not a GeoTIFF (see /var/log/my jobs/1)"
    shown = strip_paths({"sources": ["/srv/survey data/zone a.tif"], "message": message})
    assert shown["sources"] == ["zone a.tif"]
    assert shown["message"] == "cannot read zone a.tif: not a GeoTIFF (see 1)"
    assert "survey" not in str(shown) and "srv" not in str(shown)


def test_post_jobs_declares_its_token(client) -> None:
    operation = client.get("/openapi.json").json()["paths"]["/jobs"]["post"]
    assert operation["security"] == [{"bearer": []}]


def test_refused_preflight_and_malformed_http_answer_json(client, live_server: str) -> None:
    r = client.options("/collections", headers={"Origin": "http://evil.example",
                                                "Access-Control-Request-Method": "DELETE"})
    assert (r.status_code, r.json()["code"]) == (400, "CorsRefused")
    assert "origin" in r.json()["message"]
    answer = raw_exchange(live_server, b"NOT HTTP AT ALL\r\n\r\n")
    head, _, body = answer.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 400") and b"Content-Type: application/json" in head
    assert httpx.Response(400, content=body).json()["code"] == "InvalidParameterValue"
