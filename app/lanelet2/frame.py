"""The map's coordinate frame and its element ids.

Geometry is built in metres in the UTM zone of the map origin, relative to the origin:
exactly the coordinates lanelet2's ``UtmProjector(Origin(lat, lon))`` (and Autoware's
``LocalCartesianUTM`` projector) compute from the lat/lon written, and the ``local_x`` /
``local_y`` tags. Ids are positive and unique across nodes, ways and relations, handed out
in call order, so a fixed processing order gives the same file every time.
"""

from __future__ import annotations

import numpy as np
from pyproj import Transformer


class IdSource:
    """Positive ids, handed out in blocks in call order."""

    def __init__(self) -> None:
        self.next = 1

    def take(self, n: int) -> np.ndarray:
        """The next ``n`` ids."""
        out = np.arange(self.next, self.next + n, dtype=np.int64)
        self.next += n
        return out



class Frame:
    """Lon/lat <-> metres in the origin's UTM zone, relative to the origin."""

    def __init__(self, utm_epsg: int, origin_lonlat: tuple[float, float]) -> None:
        self._to = Transformer.from_crs(4326, utm_epsg, always_xy=True)
        self._from = Transformer.from_crs(utm_epsg, 4326, always_xy=True)
        self.origin = np.array(self._to.transform(*origin_lonlat))

    def local(self, lonlat: np.ndarray) -> np.ndarray:
        """Map-frame metres of lon/lat rows."""
        if not len(lonlat):
            return np.zeros((0, 2))
        x, y = self._to.transform(lonlat[:, 0], lonlat[:, 1])
        return np.column_stack([x, y]) - self.origin

    def lonlat(self, local: np.ndarray) -> np.ndarray:
        """Lon/lat of map-frame rows."""
        if not len(local):
            return np.zeros((0, 2))
        lon, lat = self._from.transform(local[:, 0] + self.origin[0], local[:, 1] + self.origin[1])
        return np.column_stack([lon, lat])
