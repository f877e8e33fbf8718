"""Everything the network capability adds to the app, in one call from ``app.main``."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from fastapi import FastAPI

from app.lanelet2 import router as lanelet2
from app.network import (
    discovery_router,
    editing_router,
    features_router,
    lane_ranges_router,
    tiles_router,
)


def include_network(app: FastAPI, dependencies: Sequence[Any] = ()) -> None:
    """Mount the OGC API Features, editing, vector-tile, network discovery and Lanelet2 map
    routers, each with ``dependencies``."""
    for router in (features_router.router, editing_router.router, lane_ranges_router.router,
                   discovery_router.router, tiles_router.router, lanelet2.router):
        app.include_router(router, dependencies=list(dependencies))
