"""``--update``: a road file or an extraction matched against an existing network, proposing
a change set (:mod:`app.network.resurvey.changes`) instead of replacing the network.

Why here and not in the writer: nothing is noded or written into ``road_segments``; the new
lines are matched as they come (a re-survey's lines start and end anywhere) and only the
proposals are stored. Accepting one then nodes it into the network like any edit.
"""

from __future__ import annotations

import getpass
from collections.abc import Iterable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from shapely.geometry.base import BaseGeometry
from sqlalchemy.orm import Session

from app.network.resurvey.changes import SurveyLine, propose
from app.network.resurvey.matching import Tolerances
from app.network.tokens import Principal
from ingest.network import GEOJSON_SUFFIXES, OSM_SUFFIXES
from ingest.network.coordinates import check_lonlat_lines
from ingest.network.file_reader import NetworkFileError, read_geojson, read_ogr
from ingest.network.model import RoadLine


def command_line_principal() -> Principal:
    """Who a change set made from the command line is by: the user running it."""
    try:
        user = getpass.getuser()
    except (KeyError, OSError):
        user = "unknown"
    return Principal(f"cli:{user}", "admin")


def survey_lines(lines: Iterable[RoadLine]) -> list[SurveyLine]:
    """Road lines as the matching takes them: lon/lat and the attributes a new road gets."""
    return [SurveyLine(list(line.coords), asdict(line.attributes)) for line in lines
            if len(line.coords) >= 2]


def read_lines(path: Path) -> list[RoadLine]:
    """Every road line of a GeoJSON / GeoPackage / OSM file (OSM ways as read by the import,
    one line per way), checked as the import checks them."""
    path = Path(path)
    if not path.is_file():
        raise NetworkFileError(f"{path}: no such file")
    name = path.name.lower()
    if name.endswith(OSM_SUFFIXES):
        from ingest.network.osm_reader import read_osm

        lines = [item for item in read_osm(path) if isinstance(item, RoadLine)]
    else:
        lines = (read_geojson(path) if name.endswith(GEOJSON_SUFFIXES) else read_ogr(path))[0]
    if not lines:
        raise NetworkFileError(f"{path.name}: no road lines found")
    check_lonlat_lines(lines, path.name)
    return lines


def update_from_file(session: Session, path: Path, network: str, *,
                     tol: Tolerances | None = None, principal: Principal | None = None
                     ) -> dict[str, Any]:
    """Propose the changes the road file ``path`` makes to ``network`` (a change set)."""
    return propose(session, network, survey_lines(read_lines(path)),
                   source=f"file:{Path(path).name}", coverage=None,
                   principal=principal or command_line_principal(), tol=tol)


def update_from_lines(session: Session, network: str, lines: list[RoadLine], source: str,
                      coverage: BaseGeometry, layer: tuple[int, int], *,
                      tol: Tolerances | None = None, principal: Principal | None = None
                      ) -> dict[str, Any]:
    """Propose the changes an extraction of a layer (``lines``, within the layer's footprints
    ``coverage``) makes to ``network``."""
    return propose(session, network, survey_lines(lines), source=source, coverage=coverage,
                   principal=principal or command_line_principal(), tol=tol, layer=layer)
