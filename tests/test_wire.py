"""``app.api.wire``: response heads respelled on their way to the socket, bodies untouched."""

from __future__ import annotations

from app.api.wire import RespelledHead, canonical, respelled
from testkit.server import raw_exchange


class Sink:
    """A transport that keeps what is written."""

    def __init__(self) -> None:
        self.written: list[bytes] = []
        self.closed = False

    def write(self, data: bytes) -> None:
        self.written.append(bytes(data))

    def is_closing(self) -> bool:
        return self.closed

    def close(self) -> None:
        self.closed = True


def test_names_take_their_conventional_spelling() -> None:
    assert canonical(b"content-type") == b"Content-Type"
    assert canonical(b"etag") == b"ETag"
    assert canonical(b"www-authenticate") == b"WWW-Authenticate"
    assert canonical(b"x-lanelet2-origin") == b"X-Lanelet2-Origin"
    head = (b"HTTP/1.1 201 Created\r\nlocation: /a?b=c:d\r\nallow: GET, POST\r\n"
            b"content-crs: <http://www.opengis.net/def/crs/OGC/1.3/CRS84>\r\n\r\nallow: body")
    assert respelled(head) == (
        b"HTTP/1.1 201 Created\r\nLocation: /a?b=c:d\r\nAllow: GET, POST\r\n"
        b"Content-Crs: <http://www.opengis.net/def/crs/OGC/1.3/CRS84>\r\n\r\nallow: body")


def test_the_head_is_respelled_and_leaves_with_the_body() -> None:
    """An interim ``100 Continue`` passes at once; the head after it is respelled and held
    until the body's first bytes (one write); later writes, whatever they hold, are left
    alone; a head with no body after it leaves when flushed or closed."""
    sink = Sink()
    transport = RespelledHead(sink)  # type: ignore[arg-type]
    transport.write(b"HTTP/1.1 100 Continue\r\n\r\n")
    transport.write(b"HTTP/1.1 200 OK\r\ncontent-length: 36\r\n\r\n")
    assert sink.written == [b"HTTP/1.1 100 Continue\r\n\r\n"]
    transport.write(b"HTTP/1.1 200 OK\r\ncontent-type: x\r\n\r\n")
    transport.write(b"more")
    assert sink.written[1:] == [b"HTTP/1.1 200 OK\r\nContent-Length: 36\r\n\r\n"
                                b"HTTP/1.1 200 OK\r\ncontent-type: x\r\n\r\n", b"more"]
    assert transport.is_closing() is False  # the rest of the transport is the socket's
    bodiless = Sink()
    held = RespelledHead(bodiless)  # type: ignore[arg-type]
    held.write(b"HTTP/1.1 204 No Content\r\netag: \"1\"\r\n\r\n")
    held.close()
    assert bodiless.written == [b"HTTP/1.1 204 No Content\r\nETag: \"1\"\r\n\r\n"]
    assert bodiless.closed


def test_pipelined_requests_each_get_a_respelled_head(live_server: str) -> None:
    """Two requests sent at once on one connection (the second waits for the first, in
    uvicorn's pipeline): both heads spelled conventionally, both bodies intact."""
    answer = raw_exchange(live_server,
                       b"GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n"
                       b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
    first, second = answer.split(b"HTTP/1.1 200 OK\r\n")[1:]
    for response in (first, second):
        head, _, body = response.partition(b"\r\n\r\n")
        names = [line.split(b":")[0] for line in head.split(b"\r\n")]
        assert b"Content-Type" in names and b"Content-Length" in names
        assert all(name == canonical(name) for name in names), names
        assert body == b'{"status":"ok"}'


def test_head_and_empty_answers_leave_whole(live_server: str) -> None:
    """A HEAD (no body bytes are written) and an OPTIONS answer (an empty body) still send
    their head, then the next request on the connection is answered."""
    answer = raw_exchange(live_server,
                       b"HEAD /healthz HTTP/1.1\r\nHost: x\r\n\r\n"
                       b"OPTIONS /healthz HTTP/1.1\r\nHost: x\r\n\r\n"
                       b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
    heads = answer.split(b"HTTP/1.1 ")[1:]
    assert [h[:3] for h in heads] == [b"200", b"200", b"200"]
    assert b"Content-Length: 15" in heads[0] and heads[0].endswith(b"\r\n\r\n")
    assert b"Allow: GET, HEAD, OPTIONS" in heads[1] and heads[1].endswith(b"\r\n\r\n")
    assert heads[2].endswith(b'{"status":"ok"}')
