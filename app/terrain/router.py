"""``GET /layers/{slug}/elevation?points=lon,lat;...``: heights of an elevation layer at points
(bilinear, null outside the layer or on nodata), read as layers are: public."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter
from fastapi import Query as QueryParam

from app import errors
from app.api.errors import responses
from app.api.query import only_query
from app.db.session import get_engine
from app.params import LayerSlug
from app.routing.options import parse_points
from app.terrain.heights import heights_at

#: Points one request may ask for (a dense route's waypoints fit; a grid does not).
MAX_POINTS = 10_000
router = APIRouter(tags=["raster layers"], dependencies=[only_query("points")],
                   responses=responses(errors.InvalidParameterValueError,
                                       errors.LayerNotFoundError,
                                       errors.DatabaseUnavailableError))


@router.get("/layers/{slug}/elevation")
def elevation(slug: LayerSlug,
              points: Annotated[str, QueryParam(description="lon,lat;lon,lat;...")]
              ) -> dict[str, Any]:
    """Heights in metres at each point, in order; ``null`` where the layer has no data."""
    lonlats = parse_points(points, MAX_POINTS)
    with get_engine().connect() as conn:
        heights = heights_at(conn, slug, lonlats)
    return {"layer": slug, "heights": [None if h is None else round(h, 3) for h in heights],
            "points": [list(p) for p in lonlats]}
