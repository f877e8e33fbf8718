"""HTTP behaviour every endpoint shares, as ASGI middleware: HEAD, CORS and gzip.

Starlette's own CORS and gzip middleware do the work (gzip with ISA-L's deflate:
:mod:`app.api.compression`); this module only chooses their settings and adds what they lack:
HEAD on every GET resource (FastAPI routes answer only the methods they declare) and two CORS
policies, because reading public map data from any web page is the point of a tile server
while writes (and anything carrying a token) must come only from pages the operator trusts.
"""

from __future__ import annotations

from fastapi import FastAPI
from starlette.datastructures import Headers
from starlette.middleware.cors import CORSMiddleware
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.api.compression import IsalGZipMiddleware
from app.settings import Settings

SAFE = ("GET", "HEAD")
WRITES = ("GET", "HEAD", "POST", "PATCH", "PUT", "DELETE")
# Response headers a cross-origin script may read (the rest of the safelist is implicit).
EXPOSED = ("ETag", "Retry-After", "WWW-Authenticate", "X-Tile-Cache", "X-Lanelet2-Origin")
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


class CorsMiddleware:
    """Two Starlette CORS policies: reads (GET/HEAD without a token) for ``read_origins``,
    anything else (writes, or a request that carries ``Authorization``) only for
    ``write_origins``, with credentials allowed."""

    def __init__(self, app: ASGIApp, read_origins: list[str],
                 write_origins: list[str]) -> None:
        self.reads = CORSMiddleware(app, allow_origins=read_origins, allow_methods=SAFE,
                                    allow_headers=("If-None-Match",), expose_headers=EXPOSED)
        self.writes = CORSMiddleware(
            app, allow_origins=write_origins, allow_methods=WRITES,
            allow_headers=("Authorization", "Content-Type", "If-Match", "If-None-Match"),
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
    """Add the shared middleware, innermost first: gzip, CORS, HEAD (so a HEAD reports the
    headers of the compressed GET, CORS headers included)."""
    app.add_middleware(IsalGZipMiddleware, minimum_size=GZIP_MIN_BYTES)
    app.add_middleware(CorsMiddleware, read_origins=settings.cors_read_origin_list,
                       write_origins=settings.cors_write_origin_list)
    app.add_middleware(HeadMiddleware)
