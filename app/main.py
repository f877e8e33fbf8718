"""The HTTP service: composes each capability's router, the error handlers and the middleware.

Like titiler's application module, this file only wires things together; every endpoint
lives in the folder of its capability, every fault class in :mod:`app.errors` and its HTTP
answer in :mod:`app.api.errors`.
"""

from __future__ import annotations

from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

from fastapi import Depends, FastAPI
from fastapi.exceptions import RequestValidationError
from sqlalchemy.exc import InterfaceError, OperationalError
from starlette.exceptions import HTTPException
from starlette.types import ASGIApp

from app import collector, errors, malloc
from app.api import document, landing, middleware
from app.api.body_limit import JsonPayloadTooLarge
from app.api.errors import api_error, database_unavailable, http_error, validation_error
from app.api.query import single_valued_query
from app.api.request_log import RequestLogMiddleware
from app.health.router import router as health_router
from app.jobs.router import router as jobs_router
from app.labels.router import router as labels_router
from app.network.resurvey.router import router as changes_router
from app.network.router import include_network
from app.previews.router import router as previews_router
from app.routing.lane_router import install_lane
from app.routing.router import include_routing
from app.settings import get_settings
from app.tiles.router import router as tiles_router
from app.web.router import include_web

# The one table of error handlers: ours, the framework's, and a lost database all answer
# {"code", "message"[, "errors"]}, so a client parses one shape whatever went wrong.
EXCEPTION_HANDLERS: dict[Any, Callable[..., Any]] = {
    errors.UgvmapError: api_error,
    HTTPException: http_error,
    RequestValidationError: validation_error,
    OperationalError: database_unavailable,
    InterfaceError: database_unavailable,
}


class UgvmapApp(FastAPI):
    """FastAPI with :class:`~app.api.body_limit.JsonPayloadTooLarge` outside its whole stack (the
    body limiter sits outside user middleware, so only here can its 413 be reshaped)."""

    def build_middleware_stack(self) -> ASGIApp:
        """The framework's stack, wrapped."""
        return JsonPayloadTooLarge(super().build_middleware_stack())


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Once the process serves: garbage-collector settings for serving (:mod:`app.collector`)
    and a cap on malloc's arenas (:mod:`app.malloc`)."""
    collector.tune_for_serving()
    malloc.cap_arenas()
    yield


def create_app() -> FastAPI:
    """Build the app; a factory so each uvicorn worker and each test gets a fresh one."""
    app = UgvmapApp(
        # Counted while the body arrives (Starlette's RequestBodyLimitMiddleware), so neither a
        # large Content-Length nor a chunked body without one is read past the limit; a route
        # may set its own ``max_body_size``.
        max_body_size=get_settings().max_body_bytes,
        title="ugvmap",
        version="0.1.0",
        description="Map tiles, road network and routes for unmanned ground vehicles.",
        exception_handlers=EXCEPTION_HANDLERS,
        lifespan=lifespan,
        # app.api.document serves the API document as OpenAPI 3.0, and /docs on it.
        openapi_url=None, docs_url=None, redoc_url=None,
    )
    # Every endpoint refuses a repeated query parameter; routing does it with OSRM's code.
    single = [Depends(single_valued_query)]
    for router in (landing.router, document.router, health_router, jobs_router, tiles_router,
                   labels_router, previews_router, changes_router):
        app.include_router(router, dependencies=single)
    include_network(app, single)
    include_routing(app)
    install_lane(app)
    include_web(app)
    middleware.install(app, get_settings())
    app.add_middleware(RequestLogMiddleware)
    return app
