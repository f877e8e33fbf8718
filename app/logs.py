"""Structured logging: one JSON object per line, for the service and the batch jobs alike.

The HTTP request log (one line per request, logger ``ugvmap.request``) is written by
:mod:`app.api.request_log`.
"""

from __future__ import annotations

import json
import logging
import time
from typing import Any


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
