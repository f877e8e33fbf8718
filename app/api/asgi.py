"""The base of the plain ASGI middleware that acts on HTTP requests only.

Plain ASGI rather than Starlette's BaseHTTPMiddleware, which would copy every response body
through an extra task and cost tile throughput.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Receive, Scope, Send


class HttpMiddleware:
    """Pass lifespan and websocket traffic through untouched; hand each HTTP request to
    :meth:`http`."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Route the connection: HTTP to :meth:`http`, anything else straight to the app."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        await self.http(scope, receive, send)

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Answer one HTTP request (through ``self.app``)."""
        raise NotImplementedError
