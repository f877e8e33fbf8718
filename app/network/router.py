"""Everything the network capability adds to the app, in one call from ``app.main``."""

from __future__ import annotations

from fastapi import FastAPI

from app.lanelet2 import router as lanelet2
from app.network import discovery, editing_router, features, tiles


def include_network(app: FastAPI) -> None:
    """Mount the OGC API Features, editing, vector-tile, network discovery and Lanelet2 map
    routers."""
    app.include_router(features.router)
    app.include_router(editing_router.router)
    app.include_router(discovery.router)
    app.include_router(tiles.router)
    app.include_router(lanelet2.router)
