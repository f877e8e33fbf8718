"""``OPTIONS`` on every resource (RFC 9110; OGC API Features Part 4 requires it): 200 with
``Allow`` listing the methods the path answers, read from the route table so it cannot
disagree with what the routes do; 404 for a path nothing serves.

A middleware rather than a catch-all route: a route matching every path would turn every
unknown path into a 405. Paths whose routes answer ``OPTIONS`` themselves (collection items,
which first check the collection exists: :mod:`app.network.editing_router`) get their route.
CORS preflights (``OPTIONS`` with ``Access-Control-Request-Method``) never get here: the CORS
middleware outside answers them.
"""

from __future__ import annotations

from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Match
from starlette.types import ASGIApp, Receive, Scope, Send

from app.api.errors import allowed_methods, api_error
from app.errors import NotFoundError


class OptionsMiddleware:
    """Answer ``OPTIONS`` for every path no route answers it on."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """``Allow`` from the route table, or the route's own answer."""
        if scope["type"] != "http" or scope["method"] != "OPTIONS" or any(
                route.matches(scope)[0] == Match.FULL for route in scope["app"].router.routes):
            await self.app(scope, receive, send)
            return
        request = Request(scope)
        allow = allowed_methods(request)
        response = Response(status_code=200, headers={"Allow": allow}) if allow else \
            api_error(request, NotFoundError(f"no such path: {request.url.path[:200]}"))
        await response(scope, receive, send)
