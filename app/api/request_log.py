"""One log line per HTTP request, in the JSON format of :mod:`app.logs`."""

from __future__ import annotations

import logging
import time

from starlette.types import Message, Receive, Scope, Send

from app.api.asgi import HttpMiddleware

request_log = logging.getLogger("ugvmap.request")


class RequestLogMiddleware(HttpMiddleware):
    """Logs one line per HTTP request (method, path, query, status, bytes, duration, client),
    measured in ASGI so streaming and error responses are counted too."""

    async def http(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Pass the request on, noting the status and body size it answers with, then log it."""
        start = time.perf_counter()
        status = 500
        size = 0

        async def send_wrapper(message: Message) -> None:
            nonlocal status, size
            if message["type"] == "http.response.start":
                status = message["status"]
            elif message["type"] == "http.response.body":
                size += len(message.get("body", b""))
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            client = scope.get("client")
            request_log.info(
                "request",
                extra={
                    "fields": {
                        "method": scope["method"],
                        "path": scope["path"],
                        "query": scope.get("query_string", b"").decode("latin-1")[:500],
                        "status": status,
                        "bytes": size,
                        "duration_ms": round((time.perf_counter() - start) * 1000, 2),
                        "client": client[0] if client else None,
                    }
                },
            )
