"""How responses leave the process, for clients that read HTTP more strictly than HTTP asks.

Header names are case-insensitive (RFC 9110), but QGIS 3.34 LTR looks for ``Allow`` (in
``QgsBaseNetworkRequest::sendOPTIONS``) and ``Location`` (in
``QgsOapifCreateFeatureRequest::createFeature``) with a case-sensitive comparison, so it sees
no editing capability and cannot create a feature when a server sends ``allow`` and
``location`` (QGIS issue 61729, fixed in 2025 by PR 61814, after 3.34). Starlette keeps header
names in lower case, and uvicorn's default HTTP implementation (httptools) writes every name
lower-cased whatever the application gives it. So:

- :class:`CanonicalHeaderCase` gives every response header its conventional spelling
  (``Content-Type``, ``ETag``, ``Allow``, ``Location``, ``Content-Crs``...);
- ``ugvmap serve`` runs uvicorn's h11 implementation, which writes names as given, through
  :class:`JsonErrorH11Protocol`, which also answers a request that is not valid HTTP with the
  service's JSON error body instead of uvicorn's plain text.
"""

from __future__ import annotations

import json

import h11
from starlette.types import Message
from uvicorn.protocols.http.h11_impl import H11Protocol

from app.api.errors import STATUS_CODES
from app.api.response_start import ResponseStartMiddleware
from app.errors import InvalidParameterValueError

# Names whose conventional spelling is not plain Title-Case.
SPELLING = {b"etag": b"ETag", b"www-authenticate": b"WWW-Authenticate",
            b"content-crs": b"Content-Crs"}


def canonical(name: bytes) -> bytes:
    """``content-type`` -> ``Content-Type``; ``etag`` -> ``ETag``."""
    lower = name.lower()
    return SPELLING.get(lower) or b"-".join(part[:1].upper() + part[1:]
                                            for part in lower.split(b"-"))


class CanonicalHeaderCase(ResponseStartMiddleware):
    """ASGI middleware: response header names in their conventional case."""

    def start(self, message: Message) -> Message:
        """The same headers, names respelled."""
        return {**message, "headers": [(canonical(k), v) for k, v in message.get("headers", [])]}


class JsonErrorH11Protocol(H11Protocol):
    """uvicorn's h11 protocol, answering malformed HTTP with ``{"code", "message"}`` JSON."""

    def send_400_response(self, msg: str) -> None:
        """The 400 uvicorn sends for bytes it cannot parse as HTTP/1.1, in our error shape."""
        body = json.dumps({"code": STATUS_CODES[InvalidParameterValueError].code,
                           "message": f"the request is not valid HTTP/1.1 ({msg})"}).encode()
        headers = [(b"Content-Type", b"application/json"),
                   (b"Content-Length", str(len(body)).encode()), (b"Connection", b"close")]
        for event in (h11.Response(status_code=400, headers=headers, reason=b"Bad Request"),
                      h11.Data(data=body), h11.EndOfMessage()):
            self.transport.write(self.conn.send(event))
        self.transport.close()
