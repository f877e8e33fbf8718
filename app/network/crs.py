"""OGC API Features Part 2 (coordinate reference systems by reference) for the road network.

Stored geometries are lon/lat (EPSG:4326 in PostGIS, served as CRS84). A client may ask for
items in another CRS (``crs``), give its ``bbox`` in one (``bbox-crs``) and send geometries in
one (the ``Content-Crs`` header of POST/PUT/PATCH): QGIS does all three once the user picks a
metric CRS for the layer, so measuring and digitising in metres needs no reprojection on the
client. The reprojection itself is PostGIS's ``ST_Transform`` in the query, never ours.

Offered: CRS84 (lon/lat, the default and storage CRS), EPSG:4326 (the same datum with the
axis order EPSG defines, latitude first, which Part 2 clients honour), EPSG:3857 (web
mercator, the tile grid's) and every WGS 84 UTM zone (EPSG:32601-32660, 32701-32760). A
collection lists CRS84, 4326, 3857 and the UTM zone of its centre, the zone a user of that
network wants; the other zones are accepted too (a network may span two), so the accepted set
does not depend on the data and needs no query to check.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from app.errors import InvalidParameterValueError, UgvmapError
from app.grid import utm_epsg

CRS84 = "http://www.opengis.net/def/crs/OGC/1.3/CRS84"
EPSG_PREFIX = "http://www.opengis.net/def/crs/EPSG/0/"
# Conformance class of Part 2 (QGIS uses a collection's CRS list only when it is declared).
CONFORMANCE = "http://www.opengis.net/spec/ogcapi-features-2/1.0/conf/crs"
WEB_MERCATOR = 3857
MERCATOR_LIMIT = 20_048_966.1  # y at 85.06 deg; x spans +-20,037,508.34
UTM_EASTING = (-1_000_000.0, 2_000_000.0)  # a zone's own 6 deg and far beyond either side
UTM_NORTHING = (-10_000_000.0, 10_000_000.0)
HINT = ("use CRS84, EPSG 4326, EPSG 3857 or a WGS 84 UTM zone (EPSG 32601-32660, "
        "32701-32760) as http://www.opengis.net/def/crs/EPSG/0/<code>")


@dataclass(frozen=True)
class Crs:
    """One offered CRS: its URI, the PostGIS SRID, and what its coordinates look like."""

    uri: str
    srid: int
    lat_first: bool = False
    """EPSG:4326: coordinates are (lat, lon), as the EPSG definition orders its axes."""

    @property
    def projected(self) -> bool:
        """Metres (3857, UTM) rather than degrees."""
        return self.srid != 4326

    @property
    def header(self) -> str:
        """The value of a ``Content-Crs`` response header (Part 2 puts the URI in <>)."""
        return f"<{self.uri}>"

    @property
    def digits(self) -> int:
        """Decimals of output coordinates: 1e-15 deg, or a micrometre."""
        return 6 if self.projected else 15

    def output_sql(self, column: str = "geom") -> str:
        """SQL of the stored geometry ``column`` as GeoJSON text in this CRS, without the
        ``crs`` member PostGIS adds by default for SRIDs other than 4326 (options 0): RFC 7946
        has none, and the ``Content-Crs`` header names the CRS."""
        geometry = column
        if self.projected:
            geometry = f"ST_Transform({column}, {self.srid})"
        elif self.lat_first:
            geometry = f"ST_FlipCoordinates({column})"
        return f"ST_AsGeoJSON({geometry}, {self.digits}, 0)"

    def storage_sql(self, param: str) -> str:
        """SQL of GeoJSON text in bound parameter ``param`` (in this CRS) as stored lon/lat
        GeoJSON text, full precision."""
        geometry = f"ST_SetSRID(ST_GeomFromGeoJSON(:{param}), {self.srid})"
        if self.projected:
            geometry = f"ST_Transform({geometry}, 4326)"
        elif self.lat_first:
            geometry = f"ST_FlipCoordinates({geometry})"
        return f"ST_AsGeoJSON({geometry}, 15)"

    def check_position(self, x: float, y: float) -> str | None:
        """Why (x, y) is no position of this CRS (before it is reprojected), or None."""
        if not (math.isfinite(x) and math.isfinite(y)):
            return "positions must be finite numbers"
        if self.srid == WEB_MERCATOR:
            if abs(x) > 20_037_508.35 or abs(y) > MERCATOR_LIMIT:
                return "positions must be within EPSG:3857's extent"
        elif self.projected:
            if not (UTM_EASTING[0] <= x <= UTM_EASTING[1]
                    and UTM_NORTHING[0] <= y <= UTM_NORTHING[1]):
                return (f"positions must be UTM metres (easting {UTM_EASTING[0]:g}.."
                        f"{UTM_EASTING[1]:g}, northing {UTM_NORTHING[0]:g}.."
                        f"{UTM_NORTHING[1]:g})")
        else:
            lon, lat = (y, x) if self.lat_first else (x, y)
            if not (-180 <= lon <= 180 and -90 <= lat <= 90):
                order = "lat, lon" if self.lat_first else "lon, lat"
                return f"positions must be [{order}] within lon -180..180, lat -90..90"
        return None


DEFAULT = Crs(CRS84, 4326)
LAT_LON = Crs(f"{EPSG_PREFIX}4326", 4326, lat_first=True)


def _epsg(code: int) -> Crs | None:
    if code == 4326:
        return LAT_LON
    if code == WEB_MERCATOR or 32601 <= code <= 32660 or 32701 <= code <= 32760:
        return Crs(f"{EPSG_PREFIX}{code}", code)
    return None


def parse(value: str, what: str, error: type[UgvmapError] = InvalidParameterValueError) -> Crs:
    """A CRS URI as Part 2 writes it (``<uri>`` in headers; QGIS sends headers without the
    brackets, so both are read) -> the offered :class:`Crs`, else ``error`` naming ``what``."""
    uri = value.strip()
    if uri.startswith("<") and uri.endswith(">"):
        uri = uri[1:-1].strip()
    if uri == CRS84:
        return DEFAULT
    match = re.fullmatch(re.escape(EPSG_PREFIX) + r"([0-9]{1,5})", uri)
    found = _epsg(int(match[1])) if match else None
    if found is None:
        raise error(f"{what} {uri[:100]!r} is not offered: {HINT}")
    return found


def advertised(bbox: list[float] | None) -> list[str]:
    """The CRS list of a collection: the defaults and the UTM zone of its centre."""
    uris = [CRS84, LAT_LON.uri, f"{EPSG_PREFIX}{WEB_MERCATOR}"]
    if bbox:
        uris.append(f"{EPSG_PREFIX}{utm_epsg((bbox[0] + bbox[2]) / 2, (bbox[1] + bbox[3]) / 2)}")
    return uris
