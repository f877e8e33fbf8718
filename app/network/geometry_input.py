"""Geometries in request bodies: checked, then turned into stored lon/lat.

A client sends coordinates in the CRS its ``Content-Crs`` header names (OGC API Features
Part 2; QGIS sets it when its layer is in a metric CRS). Positions are checked in that CRS
first (finite, inside the CRS's range), so nothing absurd reaches ``ST_Transform``; PostGIS
then reprojects, and the result is checked again as lon/lat, the way every stored geometry is.
"""

from __future__ import annotations

import json
import math
from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.network import crs as crs_

MAX_POSITIONS = 100_000


def _position_problem(position: Any, crs: crs_.Crs) -> str | None:
    if not isinstance(position, list) or len(position) != 2 or not all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in position):
        order = "lat, lon" if crs.lat_first else "x, y" if crs.projected else "lon, lat"
        return f"positions must be [{order}] pairs of numbers"
    return crs.check_position(float(position[0]), float(position[1]))


def parse_geometry(session: Session, value: Any, geometry_type: str, crs: crs_.Crs
                   ) -> tuple[dict[str, Any] | None, str | None]:
    """(lon/lat GeoJSON geometry, None), or (None, why the value is no ``geometry_type`` of
    the network: a LineString of 2 to 100000 positions, or a Point)."""
    if not isinstance(value, dict) or value.get("type") != geometry_type:
        return None, f"must be a GeoJSON {geometry_type}"
    coordinates = value.get("coordinates")
    if geometry_type == "Point":
        positions = [coordinates]
    elif isinstance(coordinates, list) and 2 <= len(coordinates) <= MAX_POSITIONS:
        positions = coordinates
    else:
        return None, f"must have 2 to {MAX_POSITIONS} positions"
    for position in positions:
        problem = _position_problem(position, crs)
        if problem:
            return None, problem
    geometry = {"type": geometry_type, "coordinates": coordinates}
    if crs != crs_.DEFAULT:
        stored: str = session.execute(text(f"SELECT {crs.storage_sql('g')}"),
                                      {"g": json.dumps(geometry)}).scalar_one()
        geometry = json.loads(stored)
        for position in [geometry["coordinates"]] if geometry_type == "Point" \
                else geometry["coordinates"]:
            lon, lat = position
            if not (math.isfinite(lon) and math.isfinite(lat)
                    and -180 <= lon <= 180 and -90 <= lat <= 90):
                return None, "positions must lie within lon -180..180, lat -90..90"
    return geometry, None
