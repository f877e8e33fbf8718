"""``GET /networks/{name}/lanelet2.osm``: the Lanelet2 map of a network, or of the part of it
meeting a bbox, for a vehicle stack to download (same read rules as every network read).

The map is written to a temporary file (it streams, so a big area never sits in memory) and
sent from there; an area holding more segments than ``UGVMAP_LANELET2_MAX_SEGMENTS`` is
refused before anything is built (the CLI has no such limit).
"""

from __future__ import annotations

import shutil
import tempfile
from functools import lru_cache
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Depends, Query
from fastapi.responses import FileResponse
from pydantic_settings import BaseSettings, SettingsConfigDict
from sqlalchemy import text
from starlette.background import BackgroundTask

from app.api.dependencies import read_access
from app.api.errors import responses
from app.api.query import only_query
from app.errors import InvalidParameterValueError, NotFoundError, ResponseTooLargeError, UserError
from app.lanelet2.export import parse_area, parse_origin, write_lanelet2
from app.lanelet2.roads import AREA_WHERE, read_selection, snapshot
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
SELECT n.id, (SELECT count(*) FROM road_segments s
               WHERE s.network_id = n.id {where}) FROM networks n WHERE n.name = :name
"""


@router.get("/networks/{name}/lanelet2.osm", response_class=FileResponse,
            dependencies=[only_query("bbox", "origin")],
            responses={200: {"content": {OSM_XML: {}},
                             "description": "Lanelet2 map (OSM XML); its origin in "
                                            "X-Lanelet2-Origin"},
                       **responses(InvalidParameterValueError, NotFoundError,
                                          ResponseTooLargeError)})
def lanelet2_map(
    name: NetworkName,
    bbox: Annotated[str | None, Query(description="W,S,E,N (degrees): only the segments "
                                                  "meeting it, whole")] = None,
    origin: Annotated[str | None, Query(description="LAT,LON of the map origin (default: "
                                                    "the centre of the exported roads)")] = None,
) -> FileResponse:
    """A lane-level Lanelet2 map of the network (every lanelet tagged ``segment_id``), to
    load with lanelet2's ``UtmProjector`` around the origin in ``X-Lanelet2-Origin``."""
    area = parse_area(bbox)
    try:
        map_origin = parse_origin(origin)
    except UserError as exc:
        raise InvalidParameterValueError(str(exc)) from None
    limit = lanelet2_settings().max_segments
    folder = Path(tempfile.mkdtemp(prefix="ugvmap-lanelet2-"))
    try:
        with snapshot() as conn:
            params: dict[str, object] = {"name": name}
            where = ""
            if area is not None:
                where = AREA_WHERE
                params.update(zip("wsen", area, strict=True))
            row = conn.execute(text(COUNT_SQL.format(where=where)), params).first()
            if row is None:
                raise NotFoundError(f"network {name[:100]!r} not found")
            if row[1] > limit:
                raise ResponseTooLargeError(
                    f"the map would hold {row[1]} segments, more than the {limit} allowed "
                    "over HTTP: ask for a smaller bbox, or use `ugvmap export network`")
            selection = read_selection(conn, name, area)
        try:
            result = write_lanelet2(selection, folder / f"{name}.lanelet2.osm", map_origin)
        except UserError as exc:  # nothing in the area, or latitudes UTM cannot take
            raise (NotFoundError if row[1] == 0 else InvalidParameterValueError)(
                str(exc)) from None
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    lat, lon = result.origin
    return FileResponse(result.path, media_type=OSM_XML, filename=result.path.name,
                        headers={"X-Lanelet2-Origin": f"{lat},{lon}",
                                 "Cache-Control": "no-cache"},
                        background=BackgroundTask(shutil.rmtree, folder, ignore_errors=True))
