"""Serves the web map: the page (at ``/`` for browsers), its static files, and MapLibre GL JS.

The page is plain ES modules with no build step, so the server only hands out files. MapLibre
comes from ``app/web/node_modules`` (installed by ``npm ci`` in ``scripts/setup.sh`` at the
version pinned in ``package-lock.json``) rather than a copy in the repo or a CDN: the map must
work with no internet, and upgrading it is a lockfile change.
"""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

WEB_DIR = Path(__file__).resolve().parent
STATIC_DIR = WEB_DIR / "static"
MAPLIBRE_DIST = WEB_DIR / "node_modules" / "maplibre-gl" / "dist"


def index_page() -> FileResponse:
    """The map page, which ``/`` answers browsers with (``app.api.landing`` negotiates)."""
    # no-cache: the page names its modules by path, so a stale copy would mix versions.
    return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-cache"})


def include_web(app: FastAPI) -> None:
    """Mount the page's static files (Starlette mounts live on the app, not a router)."""
    app.mount("/web", StaticFiles(directory=STATIC_DIR), name="web-static")
    # check_dir=False: without `npm ci` the API still starts; the page then reports the
    # missing library instead of the whole service failing.
    app.mount("/vendor/maplibre-gl", StaticFiles(directory=MAPLIBRE_DIST, check_dir=False),
              name="maplibre")
