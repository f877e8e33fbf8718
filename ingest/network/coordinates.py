"""Plausibility of an imported network's coordinates, checked before anything is written.

Road files are read as lon/lat (EPSG:4326) unless they say otherwise (a GeoJSON ``crs``
member, a GeoPackage layer's CRS). A file in projected metres that forgets to say so gives
numbers like (160000, 5200000): stored as degrees they make kilometre-long segments across
the world (a 7,631 km "segment" was seen), which the planner would happily route over. So a
coordinate outside lon -180..180 / lat -90..90, or not a number at all, refuses the whole file
with the first offending feature named, and a hint when the numbers look like metres.

A file whose lines all have zero length (every vertex of each line at one point, on the
noding grid) would import as an empty network: refused too, as almost certainly a wrong file.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from app.errors import UserError
from ingest.network.model import RoadLine
from ingest.network.noding import GRID_DEG

METRE_LIKE = 1_000.0
"""Beyond this magnitude a coordinate cannot be degrees by any stretch: it is metres (or
feet) of a projected CRS."""


class CoordinateError(UserError):
    """The file's coordinates cannot be lon/lat; the message says which and why."""


def check_lonlat_lines(lines: Sequence[RoadLine], source: str) -> None:
    """Raise :class:`CoordinateError` unless every vertex is finite lon/lat and at least one
    line has a length."""
    if not lines:
        return
    sizes = np.fromiter((len(line.coords) for line in lines), np.int64, len(lines))
    coords = np.array([c for line in lines for c in line.coords], np.float64).reshape(-1, 2)
    bad = ~(np.isfinite(coords).all(axis=1) & (np.abs(coords[:, 0]) <= 180)
            & (np.abs(coords[:, 1]) <= 90))
    if bad.any():
        first = int(np.argmax(bad))
        line = int(np.searchsorted(np.cumsum(sizes), first, side="right"))
        x, y = coords[first]
        message = (f"{source}: line {line + 1} has coordinate ({x:g}, {y:g}) outside lon "
                   f"-180..180, lat -90..90 ({int(bad.sum())} of {len(coords)} vertices)")
        finite = coords[np.isfinite(coords).all(axis=1)]
        if len(finite) and np.median(np.abs(finite).max(axis=1)) > METRE_LIKE:
            message += ("; these look like projected metres (e.g. EPSG:3857 or UTM): name the "
                        'CRS in the file (GeoJSON: a "crs" member, e.g. {"type": "name", '
                        '"properties": {"name": "EPSG:3857"}}) or reproject it to lon/lat')
        raise CoordinateError(message)
    keys = np.round(coords / GRID_DEG).astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    spread = np.maximum.reduceat(keys, starts) - np.minimum.reduceat(keys, starts)
    if not spread.any():
        raise CoordinateError(f"{source}: all {len(lines)} lines have zero length (every vertex "
                              "of each line at one point); nothing to import")
