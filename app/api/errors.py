"""Faults as HTTP answers: one table from fault class to status and public code, and the
handlers that answer every error with the same body.

The core raises plain faults (:mod:`app.errors`); this is the edge that says how a client is
told, as titiler's ``DEFAULT_STATUS_CODES`` does for rio-tiler's errors. The same fault gives
the same answer whichever endpoint meets it: ``{"code", "message"[, "errors"]}`` with the
status of :data:`STATUS_CODES`. A URL family that answers differently (OSRM's URLs) passes its
own table to :func:`fault_response`. The handlers below also turn the framework's own errors
(unknown path, wrong method, request validation) and a lost database into the same body;
``app.main`` installs them as one table.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field
from http import HTTPStatus
from typing import Any

from fastapi import Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException
from starlette.middleware.body_limit import MAX_BODY_SIZE_SCOPE_KEY
from starlette.routing import Match, Mount

from app import errors as e
from app.db.session import CONFLICT_MESSAGE, conflict


# -- faults only the HTTP layer meets ---------------------------------------------------------
class CorsRefusedError(e.UgvmapError):
    """A CORS preflight for an origin, method or header this service does not allow (the
    status Starlette's CORS middleware gives it, with our body)."""


class MethodNotAllowedError(e.UgvmapError):
    """The method does not apply to this resource; the framework's 405 adds ``Allow``."""


class PayloadTooLargeError(e.UgvmapError):
    """A body over the limit, refused before it is parsed."""


class UnsupportedMediaTypeError(e.UgvmapError):
    """A body in a media type the endpoint does not read."""


@dataclass(frozen=True)
class Answer:
    """How a fault is answered: status, public code (clients branch on it) and headers."""

    status: int
    code: str
    headers: dict[str, str] = field(default_factory=dict)


# Bearer only: a Basic challenge would make browsers prompt for a password on the web map's
# requests. Basic credentials (what QGIS sends) are accepted without being asked for.
_CHALLENGE = {"WWW-Authenticate": 'Bearer realm="ugvmap"'}

Table = dict[type[e.UgvmapError], Answer]  # fault class -> its answer

# The one table of our JSON errors (a subclass without its own row answers as its base).
STATUS_CODES: Table = {
    e.UgvmapError: Answer(500, "InternalError"),
    e.InvalidParameterValueError: Answer(400, "InvalidParameterValue"),
    CorsRefusedError: Answer(400, "CorsRefused"),
    e.UnauthorizedError: Answer(401, "Unauthorized", _CHALLENGE),
    e.ForbiddenError: Answer(403, "Forbidden"),
    e.NotFoundError: Answer(404, "NotFound"),
    e.LayerNotFoundError: Answer(404, "LayerNotFound"),
    e.TileOutOfRangeError: Answer(404, "TileOutOfRange"),
    MethodNotAllowedError: Answer(405, "MethodNotAllowed"),
    e.ConflictError: Answer(409, "Conflict"),
    e.StalePreviewError: Answer(409, "StalePreview"),
    e.PreconditionFailedError: Answer(412, "PreconditionFailed"),
    PayloadTooLargeError: Answer(413, "PayloadTooLarge"),
    UnsupportedMediaTypeError: Answer(415, "UnsupportedMediaType"),
    e.InvalidValueError: Answer(422, "InvalidValue"),
    e.PreconditionRequiredError: Answer(428, "PreconditionRequired"),
    e.DatabaseUnavailableError: Answer(503, "DatabaseUnavailable", {"Retry-After": "5"}),
    e.ServiceBusyError: Answer(503, "ServiceBusy"),  # Retry-After: the lane's (fault_response)
    e.RasterSourceMissingError: Answer(500, "RasterSourceMissing"),
    e.StoreMismatchError: Answer(503, "StoreMismatch"),
    e.SchemaOutOfDateError: Answer(503, "SchemaOutOfDate"),
    # routing: OSRM's codes, which OSRM clients branch on
    e.InvalidQueryError: Answer(400, "InvalidQuery"),
    e.TooBigError: Answer(400, "TooBig"),
    e.NoSegmentError: Answer(422, "NoSegment"),
    e.NoRouteError: Answer(422, "NoRoute"),
    e.NoTripsError: Answer(422, "NoTrips"),
    e.NoMatchError: Answer(422, "NoMatch"),
    e.InvalidOptionsError: Answer(400, "InvalidOptions"),
    e.InvalidUrlError: Answer(400, "InvalidUrl"),
    e.InvalidServiceError: Answer(400, "InvalidService"),
    e.InvalidVersionError: Answer(400, "InvalidVersion"),
    e.NotImplementedOptionError: Answer(400, "NotImplemented"),
    e.ResponseTooLargeError: Answer(422, "ResponseTooLarge"),
}


def answer(fault: type[e.UgvmapError], table: Table = STATUS_CODES) -> Answer:
    """The row of ``fault``'s class, or of its nearest base that has one."""
    return next(table[cls] for cls in fault.__mro__ if cls in table)


def body_limit_message(limit: object) -> str:
    """What a 413 says: the body limit in force for the route (``UGVMAP_MAX_BODY_BYTES``)."""
    return f"the request body exceeds the limit of {limit} bytes"


class ErrorBody(BaseModel):
    """The body of every error answer, as the API document declares it."""

    code: str = Field(description="The fault's class, e.g. InvalidParameterValue")
    message: str = Field(description="What went wrong, in words")
    errors: dict[str, str] | None = Field(None, description="One message per field (422)")


def responses(*classes: type[e.UgvmapError]) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` for the errors an operation can answer with, keyed by status,
    each listing the codes it may carry: the API document says what the handlers do."""
    table: dict[int | str, dict[str, Any]] = {}
    for cls in classes:
        status, code = answer(cls).status, answer(cls).code
        entry = table.setdefault(status, {"model": ErrorBody, "description": ""})
        summary = (cls.__doc__ or "").strip().splitlines()[0]
        entry["description"] = "; ".join(filter(None, (entry["description"],
                                                        f"`{code}`: {summary}")))
    return table


def _body(code: str, message: str, errors: dict[str, str] | None = None) -> dict[str, Any]:
    body: dict[str, Any] = {"code": code, "message": message}
    if errors:
        body["errors"] = errors
    return body


def fault_response(exc: e.UgvmapError, table: Table = STATUS_CODES) -> JSONResponse:
    """The answer to a fault, as ``table`` maps it (our JSON errors by default)."""
    row = answer(type(exc), table)
    headers = dict(row.headers)
    if isinstance(exc, e.PreconditionFailedError) and exc.current is not None:  # to reload
        headers["ETag"] = f'"{exc.current}"'
    if isinstance(exc, e.ServiceBusyError):
        headers["Retry-After"] = str(exc.retry_after_s)
    return JSONResponse(_body(row.code, exc.message, exc.errors), status_code=row.status,
                        headers=headers or None)


def api_error(_: Request, exc: Exception) -> JSONResponse:
    """Render any :class:`~app.errors.UgvmapError` raised while answering a request."""
    assert isinstance(exc, e.UgvmapError)
    return fault_response(exc)


_BY_STATUS = {answer(cls).status: answer(cls).code for cls in (
    e.InvalidParameterValueError, e.UnauthorizedError, e.ForbiddenError, e.NotFoundError,
    MethodNotAllowedError, PayloadTooLargeError, UnsupportedMediaTypeError)}


def allowed_methods(request: Request) -> str:
    """Every method some route fully answers on this path (HEAD wherever GET is, OPTIONS
    wherever any is: :mod:`app.api.options`), or "" for a path no route serves. Starlette's
    own ``Allow`` names only the first route that matched the path, while e.g. an item's GET
    and PATCH live in different routers."""
    routes = [r for r in request.app.router.routes if not isinstance(r, Mount)]
    methods = {method for method in ("GET", "POST", "PUT", "PATCH", "DELETE")
               if any(route.matches({**request.scope, "method": method})[0] == Match.FULL
                      for route in routes)}
    if "GET" in methods:
        methods.add("HEAD")
    if methods:
        methods.add("OPTIONS")
    return ", ".join(sorted(methods))


def http_error(request: Request, exc: Exception) -> JSONResponse:
    """Starlette's own errors (no such path, wrong method, static file missing) get the same
    body and code as ours, instead of ``{"detail"}``; headers such as ``Allow`` are kept (and
    for a wrong method, completed)."""
    assert isinstance(exc, HTTPException)
    code = _BY_STATUS.get(exc.status_code) or re.sub(
        r"\W", "", HTTPStatus(exc.status_code).phrase.title())
    headers = dict(exc.headers or {})
    if exc.status_code == 404 and exc.detail == HTTPStatus.NOT_FOUND.phrase:
        message = f"no such path: {request.url.path[:200]}"
    elif exc.status_code == 405:
        message = f"{request.method} is not allowed on {request.url.path[:200]}"
        # Static file mounts serve GET and HEAD only.
        headers["Allow"] = allowed_methods(request) or headers.get("Allow") or "GET, HEAD"
    elif exc.status_code == 413:  # Starlette's body limit, tripped while the body was read
        message = body_limit_message(request.scope.get(MAX_BODY_SIZE_SCOPE_KEY))
    else:
        message = str(exc.detail)
    return JSONResponse(_body(code, message), status_code=exc.status_code,
                        headers=headers or None)


def _field(loc: tuple[Any, ...]) -> str:
    """``("query", "limit")`` -> ``limit``; ``("body", "points", 0)`` -> ``points.0``: the name
    the client sent, as the editing API's per-field ``errors`` use."""
    parts = loc[1:] if len(loc) > 1 and loc[0] in ("query", "path", "header", "body") else loc
    return ".".join(str(p) for p in parts) or "body"


def validation_error(_: Request, exc: Exception) -> JSONResponse:
    """FastAPI's request validation: 422 ``InvalidValue`` with one message per field, like
    every other value-rule failure."""
    assert isinstance(exc, RequestValidationError)
    errors: dict[str, str] = {}
    for err in exc.errors():
        errors.setdefault(_field(tuple(err.get("loc", ()))), str(err.get("msg", "invalid")))
    message = "; ".join(f"{k}: {v}" for k, v in errors.items())
    return fault_response(e.InvalidValueError(message, errors=errors))


log = logging.getLogger(__name__)


def database_unavailable(request: Request, exc: Exception) -> JSONResponse:
    """A connection error from SQLAlchemy anywhere becomes 503. The client learns the kind of
    failure (the driver's last words, e.g. "Connection refused"); where the database lives
    (host, port, user, database name) goes to the log, for the operator only. A deadlock or
    serialization failure is no outage but a conflict between transactions (409), for any
    request that met one outside the writes' own retry (:func:`app.db.session.retried`)."""
    if conflict(exc):
        return fault_response(e.ConflictError(CONFLICT_MESSAGE))
    detail = str(getattr(exc, "orig", None) or exc).strip().splitlines()[0]
    log.warning("database unavailable: %s", detail)
    reason = detail.rpartition(": ")[2].strip() or "no connection"
    if re.search(r"\d+\.\d+\.\d+\.\d+|port \d+|\bat \"|host|user|database \"", reason,
                 re.IGNORECASE):
        reason = "no connection"
    return fault_response(e.DatabaseUnavailableError(f"database unreachable: {reason}"))
