"""The items endpoint's query parameters: how each is parsed and how the API document declares
it, side by side so the two cannot drift apart.

OGC API Features asks for 400 on any bad or unknown parameter (a typo must not silently return
everything), so parameters are read here rather than by FastAPI's validation (422). The
declarations live under ``components/parameters`` with the names QGIS and GDAL look for
(``limit``: they read its ``maximum`` and ``default`` to choose their page size).
"""

from __future__ import annotations

import re
from datetime import UTC, date, datetime, time, timedelta
from typing import Any

from app.errors import InvalidParameterValueError
from app.network import crs as crs_
from app.network import properties as props
from app.network.collections import ItemQuery, Kind
from app.params import parse_float

CRS84 = crs_.CRS84
DEFAULT_LIMIT = 10
MAX_LIMIT = 10_000
MAX_OFFSET = 2**63 - 1
OPEN = ("..", "")
INTEGER = re.compile(r"-?[0-9]{1,30}")

PARAMETERS: dict[str, dict[str, Any]] = {
    "limit": {
        "name": "limit", "in": "query", "required": False, "style": "form", "explode": False,
        "description": f"Features per page (larger values are served as {MAX_LIMIT}).",
        "schema": {"type": "integer", "minimum": 1, "maximum": MAX_LIMIT,
                   "default": DEFAULT_LIMIT},
    },
    "offset": {
        "name": "offset", "in": "query", "required": False, "style": "form", "explode": False,
        "description": "Features to skip (the `next` link carries it).",
        "schema": {"type": "integer", "minimum": 0, "default": 0},
    },
    "bbox": {
        "name": "bbox", "in": "query", "required": False, "style": "form", "explode": False,
        "description": "Only features that intersect the box minlon,minlat,maxlon,maxlat "
                       "(or the 6-number 3D form, whose heights are ignored); minlon > maxlon "
                       "crosses the antimeridian.",
        "schema": {"type": "array", "items": {"type": "number"},
                   "oneOf": [{"minItems": 4, "maxItems": 4}, {"minItems": 6, "maxItems": 6}]},
    },
    "bbox-crs": {
        "name": "bbox-crs", "in": "query", "required": False, "style": "form", "explode": False,
        "description": "CRS of bbox (Part 2): CRS84 (default), EPSG 4326 (lat, lon order), "
                       "EPSG 3857 or a WGS 84 UTM zone, as `http://www.opengis.net/def/crs/"
                       "EPSG/0/<code>`.",
        "schema": {"type": "string", "format": "uri", "default": CRS84},
    },
    "crs": {
        "name": "crs", "in": "query", "required": False, "style": "form", "explode": False,
        "description": "CRS of the returned coordinates (Part 2; the `Content-Crs` header "
                       "names it): the same choices as `bbox-crs`.",
        "schema": {"type": "string", "format": "uri", "default": CRS84},
    },
    "datetime": {
        "name": "datetime", "in": "query", "required": False, "style": "form", "explode": False,
        "description": "An RFC 3339 instant or interval (`start/end`, `..` or empty for an "
                       "open end) matched against a segment's `updated_at`; nodes have no "
                       "time, so it is accepted and ignored for them.",
        "schema": {"type": "string"},
    },
    "f": {
        "name": "f", "in": "query", "required": False, "style": "form", "explode": False,
        "description": "Output format; GeoJSON is the only one.",
        "schema": {"type": "string", "enum": ["json", "geojson"]},
    },
}
ITEM_PARAMS = ("limit", "offset", "bbox", "bbox-crs", "crs", "datetime", "f")


def parameter_ref(name: str) -> dict[str, str]:
    """A ``$ref`` to one of :data:`PARAMETERS` in the API document."""
    return {"$ref": f"#/components/parameters/{name}"}


def filter_parameter(prop: props.Property) -> dict[str, Any]:
    """The declaration of a ``?name=value`` equality filter, in the form QGIS and GDAL turn a
    simple attribute filter into (form style, not exploded, a plain type)."""
    schema: dict[str, Any] = {"type": prop.type}
    if prop.enum:
        schema["enum"] = list(prop.enum)
    return {"name": prop.name, "in": "query", "required": False, "style": "form",
            "explode": False, "description": f"Only features whose {prop.name} equals this.",
            "schema": schema}


def int_param(name: str, value: str | None, default: int, low: int, high: int) -> int:
    """An integer parameter from ``low`` to ``high``, or 400."""
    if value is None:
        return default
    if not INTEGER.fullmatch(value):
        raise InvalidParameterValueError(f"{name} must be an integer")
    number = int(value)
    if not low <= number <= high:
        raise InvalidParameterValueError(f"{name} must be from {low} to {high}")
    return number


def paging(query: dict[str, str]) -> tuple[int, int]:
    """(limit, offset); a limit above the maximum is served as the maximum (the standard lets
    a server cap it), so a client asking for "everything" still gets pages."""
    limit = int_param("limit", query.get("limit"), DEFAULT_LIMIT, 1, 10**30)
    return min(limit, MAX_LIMIT), int_param("offset", query.get("offset"), 0, 0, MAX_OFFSET)


def parse_bbox(value: str | None, crs: crs_.Crs = crs_.DEFAULT
               ) -> tuple[float, float, float, float] | None:
    """``minx,miny,maxx,maxy`` (or 6 numbers with heights, which are dropped) in ``crs``, as
    finite ASCII numbers within the CRS's range (``1_0`` or ``٣`` are not numbers here, a
    longitude of -500 is not a longitude): anything else is a 400 rather than a query that
    silently matches something else. EPSG:4326 boxes come latitude first and are returned
    lon/lat; lon/lat boxes may cross the antimeridian (minlon > maxlon), projected ones not."""
    if value is None:
        return None
    box = [parse_float(v, "bbox") for v in value.split(",")]
    if len(box) not in (4, 6):
        raise InvalidParameterValueError(
            "bbox must be 4 or 6 numbers: minx,miny[,minz],maxx,maxy[,maxz]")
    if len(box) == 6:
        box = [box[0], box[1], box[3], box[4]]
    if crs.lat_first:
        box = [box[1], box[0], box[3], box[2]]
    for x, y in (box[:2], box[2:]):
        problem = crs.check_position(*((y, x) if crs.lat_first else (x, y)))
        if problem:
            raise InvalidParameterValueError(f"bbox {problem.replace('positions', 'corners')}")
    if box[1] > box[3] or (crs.projected and box[0] > box[2]):
        raise InvalidParameterValueError("bbox minimum must not exceed its maximum")
    return box[0], box[1], box[2], box[3]


def _instant(text: str, end: bool) -> datetime:
    """An RFC 3339 date-time (a missing offset is read as UTC) or a full date, which stands
    for its whole UTC day (its start, or with ``end`` its last microsecond)."""
    try:
        if len(text) == 10:
            day = date.fromisoformat(text)
            moment = datetime.combine(day, time.min, UTC)
            return moment + timedelta(days=1, microseconds=-1) if end else moment
        moment = datetime.fromisoformat(text)
    except ValueError:
        raise InvalidParameterValueError(
            f"datetime {text[:40]!r} is not an RFC 3339 date-time or date") from None
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)


def parse_datetime(value: str | None) -> tuple[datetime | None, datetime | None]:
    """``instant`` or ``start/end`` (``..`` or empty = open) as (start, end); 400 when
    malformed or reversed. An empty value constrains nothing."""
    if not value:
        return None, None
    if "/" not in value:
        if value in OPEN:
            raise InvalidParameterValueError("datetime must name an instant or an interval")
        return _instant(value, end=False), _instant(value, end=True)
    first, _, second = value.partition("/")
    if "/" in second:
        raise InvalidParameterValueError("datetime interval must be start/end")
    start = None if first in OPEN else _instant(first, end=False)
    stop = None if second in OPEN else _instant(second, end=True)
    if start and stop and start > stop:
        raise InvalidParameterValueError("datetime interval starts after it ends")
    return start, stop


def item_query(kind: Kind, query: dict[str, str]) -> ItemQuery:
    """The filters of an items request; 400 for a parameter the API document does not
    declare for this collection, or a value that is not what it declares."""
    queryable = {p.name: p for p in props.queryables(kind)}
    unknown = sorted(set(query) - set(ITEM_PARAMS) - set(queryable))
    if unknown:
        raise InvalidParameterValueError(f"unknown query parameter {unknown[0][:100]!r}")
    if query.get("f", "json") not in ("json", "geojson"):
        raise InvalidParameterValueError("f must be json or geojson")
    bbox_crs = crs_.parse(query.get("bbox-crs", CRS84), "bbox-crs")
    start, stop = parse_datetime(query.get("datetime"))
    equals = tuple((name, queryable[name].parse_filter(value))
                   for name, value in sorted(query.items()) if name in queryable)
    return ItemQuery(parse_bbox(query.get("bbox"), bbox_crs), start, stop, equals,
                     bbox_srid=bbox_crs.srid)


def output_crs(query: dict[str, str]) -> crs_.Crs:
    """The CRS the items are returned in (``crs``; CRS84 when absent)."""
    return crs_.parse(query.get("crs", CRS84), "crs")
