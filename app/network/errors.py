"""Errors of the network API, rendered as the service-wide ``{"code", "message"}`` JSON body.

Raising ``ApiError`` anywhere in a request (router, query or logic) ends it with the right 4xx
and leaves the transaction rolled back, so bad input never changes stored data.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse


class ApiError(Exception):
    def __init__(self, status: int, code: str, message: str, *,
                 errors: dict[str, str] | None = None,
                 headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.status, self.code, self.message = status, code, message
        self.errors, self.headers = errors, headers


def _render(_: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ApiError)
    body: dict[str, Any] = {"code": exc.code, "message": exc.message}
    if exc.errors:
        body["errors"] = exc.errors
    return JSONResponse(body, status_code=exc.status, headers=exc.headers)


def install(app: FastAPI) -> None:
    app.add_exception_handler(ApiError, _render)


def not_found(what: str) -> ApiError:
    return ApiError(404, "NotFound", f"{what} not found")


def bad_request(message: str) -> ApiError:
    return ApiError(400, "InvalidParameterValue", message)
