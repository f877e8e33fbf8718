"""Request body limit (``UGVMAP_MAX_BODY_BYTES``, 1 MB): enforced while the body is read, for
every endpoint, with or without ``Content-Length``, answered as 413 ``PayloadTooLarge`` in the
one error shape. The socket tests talk to a real server, because only there does a body arrive
in pieces (the test client reads a body whole before the app sees it)."""

from __future__ import annotations

import json
import select
import socket
import time
from urllib.parse import urlsplit

import pytest

from testkit.network_helpers import bearer, grid_network

BIG = 50 * 1024 * 1024
LIMIT = 1_000_000


@pytest.fixture(scope="module")
def net(database_url: str):
    return grid_network()


def _endpoints(net) -> list[tuple[str, str, dict[str, str]]]:
    items = f"/collections/{net.network}-segments/items"
    edit = {**bearer("admin"), "If-Match": '"1"', "Content-Type": "application/json"}
    return [("PATCH", f"{items}/1", edit), ("POST", f"{items}/1/split", edit),
            ("POST", f"/collections/{net.network}-segments/merge",
             {**edit, "If-Match": '"1", "1"'}),
            ("POST", f"{items}/1/revert?to=1", edit),
            ("POST", f"/networks/{net.network}/route", {"Content-Type": "application/json"}),
            ("GET", "/layers", {}), ("GET", "/healthz", {}), ("PUT", "/no/such/path", {})]


def _is_413(resp) -> None:
    assert resp.status_code == 413, (resp.request.method, str(resp.request.url), resp.text[:200])
    body = resp.json()
    assert body["code"] == "PayloadTooLarge"
    assert f"limit of {LIMIT} bytes" in body["message"]


def test_a_50_mb_body_is_413_on_every_endpoint(client, net) -> None:
    payload = b" " * BIG
    for method, url, headers in _endpoints(net):
        _is_413(client.request(method, url, content=payload, headers=headers))


def test_a_chunked_body_without_length_is_413(client, net) -> None:
    def chunks():
        for _ in range(BIG // 65536):
            yield b" " * 65536

    readers = [e for e in _endpoints(net) if e[0] in ("PATCH", "POST") and "revert" not in e[1]]
    for method, url, headers in readers:  # (an endpoint that reads no body never pulls it)
        _is_413(client.request(method, url, content=chunks(), headers=headers))


def test_a_body_under_the_limit_still_works(client, net) -> None:
    items = f"/collections/{net.network}-segments/items"
    fid = client.get(items).json()["features"][0]["id"]
    padded = json.dumps({"name": "padded"}) + " " * (LIMIT - 100)
    r = client.patch(f"{items}/{fid}", content=padded,
                     headers={**bearer("editor"), "If-Match": '"1"',
                              "Content-Type": "application/json"})
    assert r.status_code == 200, r.text[:200]


def _connect(base: str) -> socket.socket:
    parts = urlsplit(base)
    sock = socket.create_connection((parts.hostname, parts.port), timeout=10)
    return sock


def _response(sock: socket.socket) -> tuple[int, dict]:
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(65536)
        assert chunk, data
        data += chunk
    head, _, rest = data.partition(b"\r\n\r\n")
    status = int(head.split()[1])
    length = int(next(line.split(b":")[1] for line in head.split(b"\r\n")
                      if line.lower().startswith(b"content-length")))
    while len(rest) < length:
        rest += sock.recv(65536)
    return status, json.loads(rest[:length])


def _request_head(method: str, path: str, headers: dict[str, str]) -> bytes:
    lines = [f"{method} {path} HTTP/1.1", "Host: test"] + [f"{k}: {v}" for k, v in
                                                            headers.items()]
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


def test_declared_length_is_refused_before_the_body_is_sent(live_server, net) -> None:
    """Headers only: the server answers at once instead of waiting for 50 MB."""
    method, path, headers = _endpoints(net)[0]
    with _connect(live_server) as sock:
        sock.sendall(_request_head(method, path, {**headers, "Content-Length": str(BIG)}))
        started = time.monotonic()
        status, body = _response(sock)
    assert (status, body["code"]) == (413, "PayloadTooLarge")
    assert time.monotonic() - started < 5


def test_chunked_body_is_cut_off_while_it_streams(live_server, net) -> None:
    """Stream 64 KiB chunks without a length; the 413 arrives long before 50 MB are sent
    (what was sent past the limit sits in socket buffers, never in the server's memory)."""
    method, path, headers = _endpoints(net)[0]
    sent = 0
    with _connect(live_server) as sock:
        sock.sendall(_request_head(method, path, {**headers,
                                                  "Transfer-Encoding": "chunked"}))
        chunk = b"10000\r\n" + b" " * 65536 + b"\r\n"
        sock.settimeout(2)
        while sent < BIG and not select.select([sock], [], [], 0)[0]:
            try:
                sock.sendall(chunk)
            except (BrokenPipeError, ConnectionResetError, TimeoutError):
                break
            sent += len(chunk)
        status, body = _response(sock)
    assert (status, body["code"]) == (413, "PayloadTooLarge")
    assert sent < BIG // 4, sent
