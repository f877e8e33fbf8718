"""HTTP behaviour every endpoint shares, as ASGI middleware: HEAD, OPTIONS, CORS, gzip and
the browser security headers.

Starlette's own CORS and gzip middleware do the work (gzip with ISA-L's deflate:
:mod:`app.api.compression`); this module only chooses their settings and adds what they lack:
HEAD on every GET resource (FastAPI routes answer only the methods they declare) and two CORS
policies, because reading public map data from any web page is the point of a tile server
while writes (and anything carrying a token) must come only from pages the operator trusts.
"""

from __future__ import annotations

from fastapi import FastAPI
from starlette.datastructures import Headers, MutableHeaders
from starlette.middleware.cors import CORSMiddleware
from starlette.requests import Request
from starlette.responses import Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.api.compression import IsalGZipMiddleware
from app.api.errors import CorsRefusedError, api_error
from app.api.options import OptionsMiddleware
from app.api.response_start import ResponseStartMiddleware
from app.settings import Settings

SAFE = ("GET", "HEAD")
WRITES = ("GET", "HEAD", "POST", "PATCH", "PUT", "DELETE")
# Response headers a cross-origin script may read (the rest of the safelist is implicit).
EXPOSED = ("ETag", "Retry-After", "WWW-Authenticate", "X-Tile-Cache", "X-Lanelet2-Origin",
           "Location", "Content-Crs")
# Every response: no MIME sniffing; never framed by another page (editors paste their token
# into the web map, so it must not be clickjacked); no Referer leaving with URLs.
SECURITY_HEADERS = {"X-Content-Type-Options": "nosniff", "X-Frame-Options": "DENY",
                    "Content-Security-Policy": "frame-ancestors 'none'",
                    "Referrer-Policy": "no-referrer"}
GZIP_MIN_BYTES = 500


class HeadMiddleware:
    """Answer HEAD as the GET would, without the body: the headers (length, type, ETag,
    caching) are the GET's own, which is what HEAD promises."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Run a HEAD request as GET and drop every body chunk it sends."""
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return

        async def without_body(message: Message) -> None:
            if message["type"] == "http.response.body":
                message = {**message, "body": b""}
            await send(message)

        await self.app({**scope, "method": "GET"}, receive, without_body)


class SecurityHeaders(ResponseStartMiddleware):
    """Add :data:`SECURITY_HEADERS` to every response (a route may set its own)."""

    def start(self, message: Message) -> Message:
        """The start message with the headers added."""
        headers = MutableHeaders(scope=message)
        for name, value in SECURITY_HEADERS.items():
            headers.setdefault(name, value)
        return message


class JsonCORSMiddleware(CORSMiddleware):
    """Starlette's CORS middleware whose refused preflight answers in the service's error
    body (400 ``CorsRefused``, saying what was refused) instead of plain text."""

    def preflight_response(self, request_headers: Headers) -> Response:
        """The preflight answer; a refusal rewritten as our JSON error."""
        response = super().preflight_response(request_headers)
        if response.status_code < 400:
            return response
        reason = bytes(response.body).decode()
        refused = api_error(Request({"type": "http", "headers": []}),
                            CorsRefusedError(f"CORS preflight refused: {reason}"))
        refused.headers.update({k: v for k, v in response.headers.items()
                                if k.startswith("access-control-") or k == "vary"})
        return refused


class CorsMiddleware:
    """Two Starlette CORS policies: reads (GET/HEAD without a token) for ``read_origins``,
    anything else (writes, or a request that carries ``Authorization``) only for
    ``write_origins``, with credentials allowed."""

    def __init__(self, app: ASGIApp, read_origins: list[str],
                 write_origins: list[str]) -> None:
        self.reads = JsonCORSMiddleware(app, allow_origins=read_origins, allow_methods=SAFE,
                                    allow_headers=("If-None-Match",), expose_headers=EXPOSED)
        self.writes = JsonCORSMiddleware(
            app, allow_origins=write_origins, allow_methods=WRITES,
            allow_headers=("Authorization", "Content-Type", "Content-Crs", "If-Match",
                           "If-None-Match"),
            allow_credentials=True, expose_headers=EXPOSED)
        self.app = app

    @staticmethod
    def is_write(scope: Scope) -> bool:
        """Whether the request (or the one a preflight announces) writes or sends a token."""
        headers = Headers(scope=scope)
        asked = headers.get("access-control-request-method")
        if scope["method"] == "OPTIONS" and asked:
            wanted = {h.strip().lower()
                      for h in headers.get("access-control-request-headers", "").split(",")}
            return asked.upper() not in SAFE or "authorization" in wanted
        return scope["method"] not in SAFE or "authorization" in headers

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Hand the request to the policy that applies to it."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        policy = self.writes if self.is_write(scope) else self.reads
        await policy(scope, receive, send)


def install(app: FastAPI, settings: Settings) -> None:
    """Add the shared middleware, innermost first: OPTIONS, gzip, CORS (which answers
    preflights before OPTIONS sees them), HEAD (so a HEAD reports the headers of the
    compressed GET, CORS headers included)."""
    app.add_middleware(OptionsMiddleware)
    app.add_middleware(IsalGZipMiddleware, minimum_size=GZIP_MIN_BYTES)
    app.add_middleware(CorsMiddleware, read_origins=settings.cors_read_origin_list,
                       write_origins=settings.cors_write_origin_list)
    app.add_middleware(HeadMiddleware)
    app.add_middleware(SecurityHeaders)
