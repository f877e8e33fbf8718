"""Structured logging: one JSON object per line, and one line per HTTP request.

The request logger is a plain ASGI middleware rather than Starlette's BaseHTTPMiddleware,
which would copy every response body through an extra task and cost tile throughput.
"""

from __future__ import annotations

import json
import logging
import time
from typing import Any

from starlette.types import ASGIApp, Message, Receive, Scope, Send

request_log = logging.getLogger("ugvmap.request")


class JsonFormatter(logging.Formatter):
    """One JSON object per log line, so request logs can be filtered and aggregated by field."""
    converter = staticmethod(time.gmtime)  # timestamps in UTC, as the "Z" suffix says

    def format(self, record: logging.LogRecord) -> str:
        """The record as JSON, with any ``fields`` a caller attached merged in."""
        payload: dict[str, Any] = {
            "ts": self.formatTime(record, "%Y-%m-%dT%H:%M:%S") + f".{int(record.msecs):03d}Z",
            "level": record.levelname.lower(),
            "logger": record.name,
            "msg": record.getMessage(),
        }
        payload.update(getattr(record, "fields", {}))
        if record.exc_info:
            payload["exc"] = self.formatException(record.exc_info)
        return json.dumps(payload, default=str)


def logging_config(level: str = "INFO") -> dict[str, Any]:
    """A dictConfig for our JSON lines; also handed to uvicorn so every worker uses it."""
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "formatters": {"json": {"()": JsonFormatter}},
        "handlers": {
            "stderr": {"class": "logging.StreamHandler", "formatter": "json",
                       "stream": "ext://sys.stderr"},
        },
        "root": {"handlers": ["stderr"], "level": level.upper()},
        "loggers": {
            "uvicorn": {"handlers": [], "propagate": True},
            "uvicorn.error": {"handlers": [], "propagate": True},
            # uvicorn's own access log would duplicate our request line.
            "uvicorn.access": {"handlers": [], "propagate": False, "level": "CRITICAL"},
            # Alembic announces its plugins at INFO when /readyz first reads the head revision.
            "alembic": {"level": "WARNING"},
        },
    }


class RequestLogMiddleware:
    """Logs one line per HTTP request (method, path, query, status, bytes, duration, client),
    measured in ASGI so streaming and error responses are counted too."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Pass the request on, noting the status and body size it answers with, then log it."""
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
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
