"""The HTTP service: composes each capability's router and the shared middleware.

Like titiler's application module, this file only wires things together; every endpoint
lives in the folder of its capability.
"""

from __future__ import annotations

from fastapi import FastAPI

from app.errors import install_error_handlers
from app.health.router import router as health_router
from app.jobs.router import router as jobs_router
from app.logs import RequestLogMiddleware
from app.network.router import include_network
from app.routing.router import include_routing
from app.tiles.router import router as tiles_router
from app.web.router import include_web


def create_app() -> FastAPI:
    app = FastAPI(
        title="ugvmap",
        version="0.1.0",
        description="Map tiles, road network and routes for unmanned ground vehicles.",
    )
    app.include_router(health_router)
    app.include_router(jobs_router)
    include_network(app)
    app.include_router(tiles_router)
    include_routing(app)
    include_web(app)
    install_error_handlers(app)
    app.add_middleware(RequestLogMiddleware)
    return app
