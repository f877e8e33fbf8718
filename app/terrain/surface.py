"""An elevation layer's off-road cost surface for one vehicle, computed once and cached.

The surface covers the whole layer on the web-mercator pixel grid of its finest zoom (a
coarser one when that would exceed :data:`MAX_CELLS`), so every route over the layer reuses
it: building it (reading the heights, slope, steps, masks) costs far more than one search.
It is kept per (layer version, vehicle settings, surface layer version, forbidding layers'
versions): a re-ingest of any of them, or other settings, build a new one.

Cells are square on the ground to within the layer's span in latitude: mercator pixels
shrink by cos(latitude), taken at the layer's centre (0.3 % across the 19 km SRTM sample).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from pyproj import Transformer
from sqlalchemy import Connection, text

from app.errors import InvalidParameterValueError, LayerNotFoundError
from app.grid import Bounds, pixel_size_m
from app.routing.profiles import OffroadSettings
from app.terrain.cost import CellCosts, cell_costs
from app.tiles.catalog import tile_sources
from app.tiles.elevation import read_heights

MAX_CELLS = 6_000_000  # ~50 MB per cached surface (heights, slope, step, cost, why)
CACHED_SURFACES = 4
TO_3857 = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)
TO_4326 = Transformer.from_crs("EPSG:3857", "EPSG:4326", always_xy=True)


@dataclass(frozen=True)
class Grid:
    """Where a surface's cells lie: ``width`` x ``height`` cells of ``res`` EPSG:3857 metres
    from the top-left corner ``left, top``; ``cell_m`` is their ground size."""

    left: float
    top: float
    res: float
    width: int
    height: int
    cell_m: float

    @property
    def bbox(self) -> Bounds:
        """The grid's extent in EPSG:3857."""
        return (self.left, self.top - self.height * self.res,
                self.left + self.width * self.res, self.top)

    def cell_of(self, lon: float, lat: float) -> tuple[int, int] | None:
        """The (row, col) of the cell holding lon/lat, or None outside the grid."""
        x, y = TO_3857.transform(lon, lat)
        col, row = math.floor((x - self.left) / self.res), math.floor((self.top - y) / self.res)
        if 0 <= row < self.height and 0 <= col < self.width:
            return row, col
        return None

    def lonlat(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lon/lat of cell centres."""
        x = self.left + (np.asarray(cols) + 0.5) * self.res
        y = self.top - (np.asarray(rows) + 0.5) * self.res
        lon, lat = TO_4326.transform(x, y)
        return np.asarray(lon), np.asarray(lat)


@dataclass(frozen=True)
class Surface:
    """A vehicle's cost surface over an elevation layer, with its heights."""

    grid: Grid
    heights: np.ndarray
    costs: CellCosts
    key: tuple = ()  # what it was made from (layers' versions, settings): its cache key


def layer_grid(conn: Connection, slug: str) -> tuple[Grid, int]:
    """The grid a surface over elevation layer ``slug`` uses, and the layer's version."""
    row = conn.execute(text(
        "SELECT kind, version, maxzoom, ST_XMin(b), ST_YMin(b), ST_XMax(b), ST_YMax(b) FROM "
        "(SELECT kind, version, maxzoom, ST_Transform(bounds, 3857) AS b FROM layers "
        " WHERE slug = :s) q"), {"s": slug}).first()
    if row is None:
        raise LayerNotFoundError(f"no raster layer {slug[:100]!r}")
    if row.kind != "elevation":
        raise InvalidParameterValueError(
            f"layer {slug} is an {row.kind} layer, not an elevation layer")
    x0, y0, x1, y1 = row[3], row[4], row[5], row[6]
    zoom = row.maxzoom
    while (x1 - x0) * (y1 - y0) / pixel_size_m(zoom) ** 2 > MAX_CELLS:
        zoom -= 1
    res = pixel_size_m(zoom)
    origin = 20037508.342789244  # the grid's corner: cells align with the layer's pixels
    left = math.floor((x0 + origin) / res) * res - origin
    top = origin - math.floor((origin - y1) / res) * res
    width, height = math.ceil((x1 - left) / res), math.ceil((top - y0) / res)
    lat = float(TO_4326.transform((x0 + x1) / 2, (y0 + y1) / 2)[1])
    return Grid(left, top, res, width, height, res * math.cos(math.radians(lat))), row.version


def _read(conn: Connection, slug: str, grid: Grid) -> np.ndarray:
    query = tile_sources(conn, slug, grid.bbox)
    if query is None:
        raise LayerNotFoundError(f"no raster layer {slug[:100]!r}")
    return read_heights(query.sources, grid.bbox, grid.width, grid.height)


def _version(conn: Connection, slug: str) -> int:
    version = conn.execute(text("SELECT version FROM layers WHERE slug = :s"),
                           {"s": slug}).scalar()
    if version is None:
        raise LayerNotFoundError(f"no raster layer {slug[:100]!r}")
    return int(version)


_cache: OrderedDict[tuple, Surface] = OrderedDict()
_lock = threading.Lock()


def surface_for(conn: Connection, elevation: str, settings: OffroadSettings,
                surface: str | None = None, forbid: tuple[str, ...] = ()) -> Surface:
    """The cost surface of ``settings`` over elevation layer ``elevation`` (the DTM), with
    steps from ``surface`` (the DSM) when given, and the cells of the ``forbid`` layers
    (any raster layer: a valid pixel above 0 forbids) never driven; cached."""
    grid, version = layer_grid(conn, elevation)
    key = (elevation, version, settings.key(),
           surface, None if surface is None else _version(conn, surface),
           tuple((f, _version(conn, f)) for f in forbid))
    with _lock:
        found = _cache.get(key)
        if found is not None:
            _cache.move_to_end(key)
            return found
    heights = _read(conn, elevation, grid)
    dsm = _read(conn, surface, grid) if surface is not None else None
    mask = None
    for slug in forbid:
        values = _read(conn, slug, grid)
        hit = np.isfinite(values) & (values > 0)
        mask = hit if mask is None else mask | hit
    made = Surface(grid, heights, cell_costs(heights, grid.cell_m, settings, dsm, mask), key)
    with _lock:
        _cache[key] = made
        while len(_cache) > CACHED_SURFACES:
            _cache.popitem(last=False)
    return made
