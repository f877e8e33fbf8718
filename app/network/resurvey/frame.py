"""The local metric frame the matching works in: an azimuthal equidistant projection centred
on the data, so distances in metres are true to well under 0.1 % across a survey area of tens
of kilometres (Web Mercator would stretch them by 1/cos(latitude))."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pyproj import Transformer


class LocalFrame:
    """lon/lat <-> metres around a centre."""

    def __init__(self, lon: float, lat: float) -> None:
        proj = f"+proj=aeqd +lat_0={lat} +lon_0={lon} +datum=WGS84 +units=m"
        self._to = Transformer.from_crs("EPSG:4326", proj, always_xy=True)
        self._from = Transformer.from_crs(proj, "EPSG:4326", always_xy=True)

    @classmethod
    def around(cls, lines: Sequence[Sequence[Sequence[float]]]) -> LocalFrame:
        """The frame centred on the bounding box of ``lines`` (lon/lat)."""
        xy = np.concatenate([np.asarray(line, float)[:, :2] for line in lines])
        (x0, y0), (x1, y1) = xy.min(0), xy.max(0)
        return cls((x0 + x1) / 2, (y0 + y1) / 2)

    def metres(self, lonlat: Sequence[Sequence[float]] | np.ndarray) -> np.ndarray:
        """(n, 2) metres of lon/lat positions."""
        a = np.asarray(lonlat, float)
        x, y = self._to.transform(a[:, 0], a[:, 1])
        return np.column_stack([x, y])

    def lonlat(self, xy: np.ndarray) -> list[list[float]]:
        """lon/lat positions (rounded to 1e-9 deg, ~0.1 mm) of (n, 2) metres."""
        lon, lat = self._from.transform(xy[:, 0], xy[:, 1])
        return [[round(float(a), 9), round(float(b), 9)] for a, b in zip(lon, lat, strict=True)]
