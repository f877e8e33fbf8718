"""Error responses shared by all routers: a JSON body with ``code`` and ``message``.

A database outage anywhere becomes 503 with the reason, never a 500 traceback.
"""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse
from sqlalchemy.exc import InterfaceError, OperationalError


def _db_unavailable(_: Request, exc: Exception) -> JSONResponse:
    detail = str(getattr(exc, "orig", None) or exc).strip().splitlines()[0]
    return JSONResponse(
        {"code": "DatabaseUnavailable", "message": f"database unreachable: {detail}"},
        status_code=503,
        headers={"Retry-After": "5"},
    )


def install_error_handlers(app: FastAPI) -> None:
    app.add_exception_handler(OperationalError, _db_unavailable)
    app.add_exception_handler(InterfaceError, _db_unavailable)
