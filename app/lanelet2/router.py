"""``GET /networks/{name}/lanelet2.osm``: the Lanelet2 map of a network, or of the part of it
meeting a bbox, for a vehicle stack to download (same read rules as every network read).

The map is written to a file (it streams, so a big area never sits in memory) and sent from
there: the whole network's is kept per network version (:mod:`app.lanelet2.cache`), an area's
is temporary. An area holding more segments than ``UGVMAP_LANELET2_MAX_SEGMENTS`` is refused
before anything is built (the CLI has no such limit); building waits for a slot of the
``lanelet2`` lane (:mod:`app.lanes`).
"""

from __future__ import annotations

import shutil
import tempfile
from functools import lru_cache
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import FileResponse
from pydantic_settings import BaseSettings, SettingsConfigDict
from sqlalchemy import Connection, text
from starlette.background import BackgroundTask
from starlette.concurrency import run_in_threadpool

from app.api.dependencies import read_access
from app.api.errors import responses
from app.api.query import only_query
from app.db.session import get_engine
from app.errors import (
    InvalidParameterValueError,
    NotFoundError,
    ResponseTooLargeError,
    ServiceBusyError,
    UserError,
)
from app.lanelet2 import cache
from app.lanelet2.export import Bbox, Lanelet2Export, parse_area, parse_origin, write_lanelet2
from app.lanelet2.roads import AREA_WHERE, read_selection, snapshot
from app.lanes import lane
from app.network.features_router import READ_ERRORS
from app.params import NetworkName

OSM_XML = "application/xml"
router = APIRouter(tags=["Vehicle maps"], dependencies=[Depends(read_access)],
                   responses=responses(*READ_ERRORS))


class Lanelet2Settings(BaseSettings):
    """Limits of the HTTP map export, from ``UGVMAP_LANELET2_*`` variables."""

    model_config = SettingsConfigDict(env_prefix="UGVMAP_LANELET2_", extra="ignore")
    max_segments: int = 100_000  # ~40 MB of map; the CLI exports any size


@lru_cache(maxsize=1)
def lanelet2_settings() -> Lanelet2Settings:
    """Read once per process (cached); tests clear it to try other limits."""
    return Lanelet2Settings()


COUNT_SQL = """
SELECT n.id, n.version, (SELECT count(*) FROM road_segments s
                          WHERE s.network_id = n.id {where}) FROM networks n WHERE n.name = :name
"""


@router.get("/networks/{name}/lanelet2.osm", response_class=FileResponse,
            dependencies=[only_query("bbox", "origin")],
            responses={200: {"content": {OSM_XML: {}},
                             "description": "Lanelet2 map (OSM XML); its origin in "
                                            "X-Lanelet2-Origin"},
                       **responses(InvalidParameterValueError, NotFoundError,
                                   ResponseTooLargeError, ServiceBusyError)})
async def lanelet2_map(
    request: Request,
    name: NetworkName,
    bbox: Annotated[str | None, Query(description="W,S,E,N (degrees): only the segments "
                                                  "meeting it, whole")] = None,
    origin: Annotated[str | None, Query(description="LAT,LON of the map origin (default: "
                                                    "the centre of the exported roads)")] = None,
) -> FileResponse:
    """A lane-level Lanelet2 map of the network (every lanelet tagged ``segment_id``), to
    load with lanelet2's ``UtmProjector`` around the origin in ``X-Lanelet2-Origin``.

    The whole network's map is built once per network version (and origin) and kept
    (:mod:`app.lanelet2.cache`), and sent as its stored gzip file to a client that accepts
    gzip; building one, or the map of a bbox, waits for a slot of the ``lanelet2`` lane
    (:mod:`app.lanes`), 503 ``ServiceBusy`` when its queue is full."""
    area = parse_area(bbox)
    try:
        map_origin = parse_origin(origin)
    except UserError as exc:
        raise InvalidParameterValueError(str(exc)) from None
    if area is None:
        network_id, version = await run_in_threadpool(_version, name)
        found = cache.cached(network_id, version, map_origin)
        if found is None:
            async with lane("lanelet2").slot():
                found = await run_in_threadpool(_whole_map, name, map_origin)
        gz = found.gzipped
        if gz is not None and "gzip" in request.headers.get("accept-encoding", ""):
            return _file(cache.CachedMap(gz, found.origin), name,
                         headers={"Content-Encoding": "gzip"})
        return _file(found, name)
    async with lane("lanelet2").slot():
        part, folder = await run_in_threadpool(_area_map, name, area, map_origin)
    return _file(part, name, folder)


def _counted(conn: Connection, name: str, area: Bbox | None) -> tuple[int, int, int]:
    """(network id, version, segments to map), refusing an unknown network or a map over
    ``UGVMAP_LANELET2_MAX_SEGMENTS`` before anything is built."""
    params: dict[str, object] = {"name": name}
    where = ""
    if area is not None:
        where = AREA_WHERE
        params.update(zip("wsen", area, strict=True))
    row = conn.execute(text(COUNT_SQL.format(where=where)), params).first()
    if row is None:
        raise NotFoundError(f"network {name[:100]!r} not found")
    limit = lanelet2_settings().max_segments
    if row[2] > limit:
        raise ResponseTooLargeError(
            f"the map would hold {row[2]} segments, more than the {limit} allowed "
            "over HTTP: ask for a smaller bbox, or use `ugvmap export network`")
    return int(row[0]), int(row[1]), int(row[2])


def _version(name: str) -> tuple[int, int]:
    """(network id, version) of network ``name``, 404 when there is none."""
    with get_engine().connect() as conn:
        row = conn.execute(text("SELECT id, version FROM networks WHERE name = :name"),
                           {"name": name}).first()
    if row is None:
        raise NotFoundError(f"network {name[:100]!r} not found")
    return int(row[0]), int(row[1])


def _written(name: str, area: Bbox | None, origin: tuple[float, float] | None,
             folder: Path) -> tuple[int, int, Lanelet2Export]:
    """Read one consistent view of the network and write its map into ``folder``:
    (network id, version, the export)."""
    with snapshot() as conn:
        network_id, version, count = _counted(conn, name, area)
        selection = read_selection(conn, name, area)
    try:
        return network_id, version, write_lanelet2(selection, folder / f"{name}.lanelet2.osm",
                                                   origin)
    except UserError as exc:  # nothing in the area, or nothing UTM can hold
        raise (NotFoundError if count == 0 else InvalidParameterValueError)(str(exc)) from None


def _whole_map(name: str, origin: tuple[float, float] | None) -> cache.CachedMap:
    """The stored whole-network map of the current version, built now unless a request
    that held the lane before this one already has."""
    network_id, version = _version(name)
    found = cache.cached(network_id, version, origin)
    if found is not None:
        return found
    cache.cache_dir().mkdir(parents=True, exist_ok=True)
    folder = Path(tempfile.mkdtemp(prefix="build-", dir=cache.cache_dir()))
    try:
        network_id, version, result = _written(name, None, origin, folder)
        return cache.store(result.path, network_id, version, origin, result.origin)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _area_map(name: str, area: Bbox, origin: tuple[float, float] | None
              ) -> tuple[cache.CachedMap, Path]:
    """The map of the segments meeting ``area``, in a temporary folder of its own (removed
    once sent)."""
    folder = Path(tempfile.mkdtemp(prefix="ugvmap-lanelet2-"))
    try:
        _, _, result = _written(name, area, origin, folder)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    return cache.CachedMap(result.path, result.origin), folder


def _file(found: cache.CachedMap, name: str, folder: Path | None = None,
          headers: dict[str, str] | None = None) -> FileResponse:
    """The map as a download, with its origin; ``folder`` is removed once it is sent."""
    lat, lon = found.origin
    return FileResponse(found.path, media_type=OSM_XML, filename=f"{name}.lanelet2.osm",
                        headers={"X-Lanelet2-Origin": f"{lat},{lon}",
                                 "Cache-Control": "no-cache", "Vary": "Accept-Encoding",
                                 **(headers or {})},
                        background=None if folder is None else
                        BackgroundTask(shutil.rmtree, folder, ignore_errors=True))
