"""Request body size limit: Starlette's, answered in our error shape.

The limit itself is Starlette's ``RequestBodyLimitMiddleware`` (``FastAPI(max_body_size=...)``,
from ``UGVMAP_MAX_BODY_BYTES``; a route may set its own ``max_body_size``). It counts bytes as
they arrive, so a 50 MB body, with or without ``Content-Length`` (chunked), is stopped at the
limit while being read, never buffered whole. A body over the limit while an endpoint reads it
reaches the app's handler table as an ``HTTPException(413)``; but when ``Content-Length``
already declares too much, the middleware itself answers with a plain-text "Content Too Large"
(replacing whatever the endpoint answered). :class:`JsonPayloadTooLarge` sits outside it and
rewrites that one answer into the ``{"code", "message"}`` body every other error has.
"""

from __future__ import annotations

import json

from starlette.datastructures import Headers
from starlette.middleware.body_limit import MAX_BODY_SIZE_SCOPE_KEY
from starlette.types import Message, Receive, Scope, Send

from app.api.asgi import HttpMiddleware
from app.api.errors import STATUS_CODES, PayloadTooLargeError, body_limit_message


class JsonPayloadTooLarge(HttpMiddleware):
    """Outermost ASGI wrapper: a plain-text 413 from the body limiter becomes our JSON error."""

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Pass everything through except a plain-text 413, whose body is replaced."""
        replacing = False

        async def send_json(message: Message) -> None:
            nonlocal replacing
            if message["type"] == "http.response.start" and message["status"] == 413 and \
                    Headers(raw=message["headers"]).get("content-type", "").startswith(
                        "text/plain"):
                replacing = True
                return
            if replacing and message["type"] == "http.response.body":
                body = json.dumps({"code": STATUS_CODES[PayloadTooLargeError].code, "message":
                                   body_limit_message(scope.get(MAX_BODY_SIZE_SCOPE_KEY))})
                await send({"type": "http.response.start", "status": 413, "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                    (b"connection", b"close")]})
                await send({"type": "http.response.body", "body": body.encode()})
                replacing = False
                return
            await send(message)

        await self.app(scope, receive, send_json)
