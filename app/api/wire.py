"""How responses leave the process, for clients that read HTTP more strictly than HTTP asks.

Header names are case-insensitive (RFC 9110), but QGIS 3.34 LTR looks for ``Allow`` (in
``QgsBaseNetworkRequest::sendOPTIONS``) and ``Location`` (in
``QgsOapifCreateFeatureRequest::createFeature``) with a case-sensitive comparison, so it sees
no editing capability and cannot create a feature when a server sends ``allow`` and
``location`` (QGIS issue 61729, fixed in 2025 by PR 61814, after 3.34). Starlette keeps header
names in lower case, and uvicorn's fast HTTP implementation (httptools) writes every name
lower-cased whatever the application gives it.

``ugvmap serve`` runs httptools through :class:`ServiceHttpProtocol`, which gives every
response header its conventional spelling (``Content-Type``, ``ETag``, ``Allow``,
``Location``, ``Content-Crs``...) as the head leaves for the socket (:class:`RespelledHead`),
and answers a request that is not valid HTTP with the service's JSON error body instead of
uvicorn's plain text. Why not uvicorn's h11 implementation, which writes names as given (it
served until 2026-11): it is pure Python, and cost every request ~0.1 ms (29-31 % fewer
requests per second than httptools on ``/healthz``, a cached tile or a feature page,
``bench/http_protocol.py``); the respelling costs 2-8 %.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol, RequestResponseCycle

from app.api.errors import STATUS_CODES
from app.errors import InvalidParameterValueError, TooBigError, UgvmapError

# Names whose conventional spelling is not plain Title-Case.
SPELLING = {b"etag": b"ETag", b"www-authenticate": b"WWW-Authenticate",
            b"content-crs": b"Content-Crs"}
INTERIM = b"HTTP/1.1 100 "  # "100 Continue", written before the head of the response
MAX_URL_BYTES = 65_535
"""The longest request target read. httptools' URL parser keeps offsets in 16 bits, so a
longer one (10,000 coordinates in an OSRM URL) failed as "not valid HTTP/1.1"; and nothing
else bounded how much of a URL the protocol would gather in memory."""

LINGER_S = 5.0  # how long a refused request's connection waits for the client to stop sending


class UrlTooLongError(Exception):
    """Raised from the parser's URL callback: httptools stops parsing and uvicorn answers
    through :meth:`ServiceHttpProtocol.send_400_response`."""


def canonical(name: bytes) -> bytes:
    """``content-type`` -> ``Content-Type``; ``etag`` -> ``ETag``."""
    lower = name.lower()
    return SPELLING.get(lower) or b"-".join(part[:1].upper() + part[1:]
                                            for part in lower.split(b"-"))


def respelled(head: bytes) -> bytes:
    """A response head (status line, ``name: value`` lines, blank line, perhaps the start of
    the body) with every header name spelled by :func:`canonical`."""
    fields, blank, rest = head.partition(b"\r\n\r\n")
    status, *lines = fields.split(b"\r\n")
    out = [status]
    for line in lines:
        name, sep, value = line.partition(b":")
        out.append(canonical(name) + sep + value)
    return b"\r\n".join(out) + blank + rest


class RespelledHead:
    """The transport one response is written to: its head (which uvicorn writes whole, in one
    call) respelled and held until the body's first bytes, so that both leave in one write:
    one system call and one wake-up of the client instead of two (A/B on live servers: -0.07
    ms of a 1.8 ms Andorra route, -0.04 ms of ``/healthz``); the rest passed through
    untouched."""

    def __init__(self, transport: asyncio.Transport) -> None:
        self._transport = transport
        self._head_seen = False
        self._head: bytes | None = None  # respelled, waiting for the body

    def write(self, data: bytes | bytearray | memoryview) -> None:
        """Write ``data``: hold it when it is the response's head, else send it after the
        head held."""
        if not self._head_seen:
            if bytes(data[:len(INTERIM)]) == INTERIM:  # "100 Continue" goes at once
                self._transport.write(data)
                return
            self._head_seen = True
            self._head = respelled(bytes(data))
            return
        if self._head is not None:
            data, self._head = self._head + bytes(data), None
        self._transport.write(data)

    def flush(self) -> None:
        """Send a head still held (a response without body bytes: HEAD, an empty answer)."""
        if self._head is not None:
            self._transport.write(self._head)
            self._head = None

    def close(self) -> None:
        """Close the connection after whatever is held."""
        self.flush()
        self._transport.close()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._transport, name)


class ServiceHttpProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol, writing header names in their conventional case and
    answering malformed HTTP with ``{"code", "message"}`` JSON."""

    _lingering = False  # set once a refusal is written: what the client still sends is dropped

    def _start_asgi_task(self, cycle: RequestResponseCycle, app: Any) -> None:
        # Every request's cycle starts here, pipelined ones included, before it writes.
        head = RespelledHead(cycle.transport)
        cycle.transport = head  # type: ignore[assignment]
        send = cycle.send

        async def sent(message: Any) -> None:
            await send(message)
            if message["type"] == "http.response.body" and not message.get("more_body"):
                head.flush()

        cycle.send = sent  # type: ignore[method-assign]
        super()._start_asgi_task(cycle, app)

    def on_url(self, url: bytes) -> None:
        """Gather the request target, up to :data:`MAX_URL_BYTES`."""
        super().on_url(url)
        if len(self.url) > MAX_URL_BYTES:
            raise UrlTooLongError

    def send_400_response(self, msg: str) -> None:
        """The 400 uvicorn sends for bytes it cannot parse as HTTP/1.1, in our error shape;
        a URL over :data:`MAX_URL_BYTES` is OSRM's ``TooBig``, as too many points are."""
        fault: type[UgvmapError] = InvalidParameterValueError
        message = f"the request is not valid HTTP/1.1 ({msg})"
        if len(getattr(self, "url", b"")) > MAX_URL_BYTES:
            fault, message = TooBigError, (
                f"the URL is over {MAX_URL_BYTES:,} bytes long, the most this service reads; "
                "send long point lists as a JSON body (POST)")
        body = json.dumps({"code": STATUS_CODES[fault].code, "message": message}).encode()
        self.transport.write(b"HTTP/1.1 400 Bad Request\r\nContent-Type: application/json\r\n"
                             b"Content-Length: %d\r\nConnection: close\r\n\r\n%s"
                             % (len(body), body))
        self._linger()

    def _linger(self) -> None:
        """Close once the client has stopped sending (its EOF closes the transport), or after
        :data:`LINGER_S`: closing while the rest of its request is still arriving resets the
        connection, and the client's system then drops the answer it had received."""
        self._lingering = True
        if self.transport.can_write_eof():
            self.transport.write_eof()
        self.loop.call_later(LINGER_S, self.transport.close)

    def data_received(self, data: bytes) -> None:
        """Parse ``data``, or drop it once the connection is being closed."""
        if not self._lingering:
            super().data_received(data)
