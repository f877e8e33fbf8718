"""The service's one error model: every fault a client can cause or see has one class here.

Each :class:`ApiError` subclass fixes its HTTP status and public ``code`` at class level (the
pygeoapi/titiler pattern), so the same fault gives the same answer whichever endpoint meets
it. Raising one anywhere in a request (router, query or logic) ends the request with the body
``{"code", "message"[, "errors"]}`` and leaves the transaction rolled back, so bad input never
changes stored data. The handlers below also turn the framework's own errors (unknown path,
wrong method, request validation) and a lost database into the same body; ``app.main``
installs them as one table.

:class:`UserError` is the command line's counterpart: a mistake the user can fix, printed as
one line by the CLI root, raised by ingest code as much as by the commands themselves.
"""

from __future__ import annotations

import logging
import re
from http import HTTPStatus
from typing import Any, ClassVar

from fastapi import Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException
from starlette.middleware.body_limit import MAX_BODY_SIZE_SCOPE_KEY
from starlette.routing import Match, Mount


class UserError(ValueError):
    """A mistake the user can fix (bad file, unknown name, bad option), said in one line.

    A ``ValueError`` so callers that already treat bad values as such keep working; the CLI
    root prints it as ``Error: <message>`` with exit status 1 and no traceback.
    """


class ApiError(Exception):
    """Base of every HTTP error answer; subclasses only set ``status`` and ``code``."""

    status: ClassVar[int] = 500
    code: ClassVar[str] = "InternalError"
    default_headers: ClassVar[dict[str, str]] = {}

    def __init__(self, message: str, *, errors: dict[str, str] | None = None,
                 headers: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.errors = errors
        self.headers = {**self.default_headers, **(headers or {})} or None


class InvalidParameterValueError(ApiError):
    """A malformed query parameter, path part or body (OGC API's code for it)."""

    status, code = 400, "InvalidParameterValue"


class CorsRefusedError(ApiError):
    """A CORS preflight for an origin, method or header this service does not allow (the
    status Starlette's CORS middleware gives it, with our body)."""

    status, code = 400, "CorsRefused"


class UnauthorizedError(ApiError):
    """No valid token; says which scheme to use, as RFC 9110 requires for a 401."""

    status, code = 401, "Unauthorized"
    # Bearer only: a Basic challenge would make browsers prompt for a password on the web
    # map's requests. Basic credentials (what QGIS sends) are accepted without being asked for.
    default_headers: ClassVar[dict[str, str]] = {"WWW-Authenticate": 'Bearer realm="ugvmap"'}


class ForbiddenError(ApiError):
    """A valid token whose role may not do this."""
    status, code = 403, "Forbidden"


class NotFoundError(ApiError):
    """An unknown path, network, collection, feature or job."""
    status, code = 404, "NotFound"


class LayerNotFoundError(NotFoundError):
    """An unknown raster layer: its own code, which clients of the tile API already test for."""

    code = "LayerNotFound"


class TileOutOfRangeError(NotFoundError):
    """A well-formed tile address outside the tile-matrix set (zoom > max, x or y >= 2^z)."""

    code = "TileOutOfRange"


class MethodNotAllowedError(ApiError):
    """The method does not apply to this resource; the framework's 405 adds ``Allow``."""
    status, code = 405, "MethodNotAllowed"


class PreconditionFailedError(ApiError):
    """``If-Match`` names a version that is no longer current: someone saved first."""

    status, code = 412, "PreconditionFailed"


class PayloadTooLargeError(ApiError):
    """A body over the limit, refused before it is parsed."""
    status, code = 413, "PayloadTooLarge"


class UnsupportedMediaTypeError(ApiError):
    """A body in a media type the endpoint does not read."""
    status, code = 415, "UnsupportedMediaType"


class InvalidValueError(ApiError):
    """Well-formed input whose values break a rule; ``errors`` says which field and why."""

    status, code = 422, "InvalidValue"


class PreconditionRequiredError(ApiError):
    """A write without ``If-Match``: refused so edits cannot silently overwrite each other."""

    status, code = 428, "PreconditionRequired"


class DatabaseUnavailableError(ApiError):
    """The database cannot be reached: a 503 the client may retry, never a 500 traceback."""

    status, code = 503, "DatabaseUnavailable"
    default_headers: ClassVar[dict[str, str]] = {"Retry-After": "5"}


class RasterSourceMissingError(ApiError):
    """A tile needs a COG the raster store does not have: the catalogue and the store
    disagree (files deleted, or a process using another store); never a silent blank tile.
    The server log names the file."""

    status, code = 500, "RasterSourceMissing"


class StoreMismatchError(ApiError):
    """``/readyz`` only: this process's raster store is not the one the database's files are
    in (another ``UGVMAP_RASTER_STORE`` or data directory); the server log names both."""

    status, code = 503, "StoreMismatch"


class SchemaOutOfDateError(ApiError):
    """The database is reachable but not migrated to the code's head revision."""

    status, code = 503, "SchemaOutOfDate"


# -- routing: OSRM's codes, which OSRM clients branch on --------------------------------------
class InvalidQueryError(ApiError):
    """Malformed route points or options."""

    status, code = 400, "InvalidQuery"


class TooBigError(ApiError):
    """More points than the configured limit."""

    status, code = 400, "TooBig"


class NoSegmentError(ApiError):
    """A point is farther than the snap radius from every usable segment."""

    status, code = 422, "NoSegment"


class NoRouteError(ApiError):
    """The points are in parts of the network that do not connect (in allowed directions)."""

    status, code = 422, "NoRoute"


class NoTripsError(ApiError):
    """A trip cannot visit every point: some cannot reach each other (OSRM's trip service)."""

    status, code = 422, "NoTrips"


class NoMatchError(ApiError):
    """No two consecutive points of a trace could be matched to roads (OSRM's match)."""

    status, code = 422, "NoMatch"


class InvalidOptionsError(ApiError):
    """Route options that parse but do not fit together (one radius per point, ...)."""

    status, code = 400, "InvalidOptions"


class InvalidUrlError(ApiError):
    """An OSRM-shaped URL that cannot be read (a bad network name or coordinates part)."""

    status, code = 400, "InvalidUrl"


class InvalidServiceError(ApiError):
    """An OSRM service not served here (``tile``, or one OSRM does not have)."""

    status, code = 400, "InvalidService"


class InvalidVersionError(ApiError):
    """An OSRM protocol version other than ``v1``."""

    status, code = 400, "InvalidVersion"


class NotImplementedOptionError(ApiError):
    """A well-formed OSRM option this server does not implement: refused, never ignored."""

    status, code = 400, "NotImplemented"


class ResponseTooLargeError(ApiError):
    """An answer over the configured output caps (coordinates, waypoints): refused before it is
    built, so one request cannot make a worker allocate without bound."""

    status, code = 422, "ResponseTooLarge"


# OSRM's own server answers every error with 400; on the OSRM-shaped URLs the same faults keep
# their code and take that status, so OSRM clients branch as they do against OSRM.
class OsrmInvalidValueError(InvalidValueError):
    """:class:`InvalidValueError` on an OSRM-shaped URL."""

    status = 400


class OsrmNoSegmentError(NoSegmentError):
    """:class:`NoSegmentError` on an OSRM-shaped URL."""

    status = 400


class OsrmNoRouteError(NoRouteError):
    """:class:`NoRouteError` on an OSRM-shaped URL."""

    status = 400


class OsrmNoTripsError(NoTripsError):
    """:class:`NoTripsError` on an OSRM-shaped URL."""

    status = 400


class OsrmNoMatchError(NoMatchError):
    """:class:`NoMatchError` on an OSRM-shaped URL."""

    status = 400


class OsrmTooBigError(TooBigError):
    """:class:`ResponseTooLargeError` on an OSRM-shaped URL: OSRM calls every size limit
    ``TooBig``."""


def body_limit_message(limit: object) -> str:
    """What a 413 says: the body limit in force for the route (``UGVMAP_MAX_BODY_BYTES``)."""
    return f"the request body exceeds the limit of {limit} bytes"


class ErrorBody(BaseModel):
    """The body of every error answer, as the API document declares it."""

    code: str = Field(description="The fault's class, e.g. InvalidParameterValue")
    message: str = Field(description="What went wrong, in words")
    errors: dict[str, str] | None = Field(None, description="One message per field (422)")


def responses(*classes: type[ApiError]) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` for the errors an operation can answer with, keyed by status,
    each listing the codes it may carry: the API document says what the handlers do."""
    table: dict[int | str, dict[str, Any]] = {}
    for cls in classes:
        entry = table.setdefault(cls.status, {"model": ErrorBody, "description": ""})
        summary = (cls.__doc__ or "").strip().splitlines()[0]
        entry["description"] = "; ".join(filter(None, (entry["description"],
                                                        f"`{cls.code}`: {summary}")))
    return table


def _body(code: str, message: str, errors: dict[str, str] | None = None) -> dict[str, Any]:
    body: dict[str, Any] = {"code": code, "message": message}
    if errors:
        body["errors"] = errors
    return body


def api_error(_: Request, exc: Exception) -> JSONResponse:
    """Render any :class:`ApiError` raised while answering a request."""
    assert isinstance(exc, ApiError)
    return JSONResponse(_body(exc.code, exc.message, exc.errors), status_code=exc.status,
                        headers=exc.headers)


_BY_STATUS = {cls.status: cls for cls in (
    InvalidParameterValueError, UnauthorizedError, ForbiddenError, NotFoundError,
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
    cls = _BY_STATUS.get(exc.status_code)
    code = cls.code if cls else re.sub(r"\W", "", HTTPStatus(exc.status_code).phrase.title())
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
    return api_error(_, InvalidValueError(message, errors=errors))


log = logging.getLogger(__name__)


def database_unavailable(request: Request, exc: Exception) -> JSONResponse:
    """A connection error from SQLAlchemy anywhere becomes 503. The client learns the kind of
    failure (the driver's last words, e.g. "Connection refused"); where the database lives
    (host, port, user, database name) goes to the log, for the operator only."""
    detail = str(getattr(exc, "orig", None) or exc).strip().splitlines()[0]
    log.warning("database unavailable: %s", detail)
    reason = detail.rpartition(": ")[2].strip() or "no connection"
    if re.search(r"\d+\.\d+\.\d+\.\d+|port \d+|\bat \"|host|user|database \"", reason,
                 re.IGNORECASE):
        reason = "no connection"
    return api_error(request, DatabaseUnavailableError(f"database unreachable: {reason}"))
