"""Checks of terrain answers against independent references, shared by the terrain tests and
``bench/offroad.py``: slope tiles against ``gdaldem slope``, a road join against brute force."""

from __future__ import annotations

import itertools
import subprocess
from pathlib import Path

import networkx as nx
import numpy as np
import rasterio
from pyproj import Transformer
from scipy.ndimage import map_coordinates
from skimage.graph import MCP_Geometric
from sqlalchemy import Connection, text

from app.grid import tile_bounds
from app.terrain.roads import Roads
from app.terrain.surface import Surface
from app.tiles.catalog import tile_sources
from app.tiles.elevation import slope_grid
from testkit.raster_synth import TMS


def gdaldem_slope_at(dem: Path, tmp_path: Path, lonlats: np.ndarray) -> np.ndarray:
    """``gdaldem slope`` of ``dem`` (its own CRS and grid), bilinear at each lon/lat (NaN near
    its nodata and edges)."""
    out = tmp_path / f"{dem.stem}-slope.tif"
    subprocess.run(["gdaldem", "slope", "-q", str(dem), str(out)], check=True)
    with rasterio.open(out) as ds:
        xs, ys = Transformer.from_crs("EPSG:4326", ds.crs, always_xy=True).transform(
            lonlats[:, 0], lonlats[:, 1])
        slope = ds.read(1, masked=True).filled(np.nan).astype(np.float64)
        cols, rows = ~ds.transform @ (np.asarray(xs), np.asarray(ys))
    return map_coordinates(slope, [rows - 0.5, cols - 0.5], order=1, cval=np.nan)


def slope_tiles_vs_gdaldem(conn: Connection, slug: str, dem: Path, tmp_path: Path
                           ) -> tuple[float, int]:
    """Median |our slope tile - gdaldem slope| in degrees over every native-zoom tile of layer
    ``slug`` (ingested from ``dem``), compared at our tile pixels' centres; and how many
    pixels were compared."""
    row = conn.execute(text(
        "SELECT maxzoom, ARRAY[ST_XMin(bounds), ST_YMin(bounds), ST_XMax(bounds), "
        "ST_YMax(bounds)] FROM layers WHERE slug = :s"), {"s": slug}).one()
    zoom: int = row[0]
    bounds: list[float] = row[1]
    got, where = [], []
    west, south, east, north = bounds
    for t in TMS.tiles(west, south, east, north, [zoom]):
        bbox = tile_bounds(zoom, t.x, t.y)
        query = tile_sources(conn, slug, bbox)
        assert query is not None
        slope = slope_grid(query.sources, bbox, 256)
        res = (bbox[2] - bbox[0]) / 256
        cols, rows = np.meshgrid(np.arange(256) + 0.5, np.arange(256) + 0.5)
        keep = np.isfinite(slope)
        got.append(slope[keep])
        where.append(np.stack([bbox[0] + cols[keep] * res, bbox[3] - rows[keep] * res], 1))
    mx, my = np.concatenate(where).T
    lon, lat = Transformer.from_crs("EPSG:3857", "EPSG:4326", always_xy=True).transform(mx, my)
    ref = gdaldem_slope_at(dem, tmp_path, np.stack([lon, lat], 1))
    ours = np.concatenate(got)
    both = np.isfinite(ref)
    return float(np.median(np.abs(ours[both] - ref[both]))), int(both.sum())


def brute_force_join(surface: Surface, roads: Roads, a: tuple[int, int],
                     b: tuple[int, int]) -> float:
    """The least time from cell ``a`` to cell ``b``: entirely off road, or off road to any
    road vertex ``u``, the roads to any ``v``, off road to ``b``, every pair tried."""
    times = []
    for cell in (a, b):
        mcp = MCP_Geometric(roads.cost, fully_connected=True,
                            sampling=(surface.grid.cell_m,) * 2)
        times.append(mcp.find_costs([cell])[0])
    along = dict(nx.all_pairs_dijkstra_path_length(roads.graph, weight="seconds"))
    joins = roads.joins()
    best = min((times[0][cu] + along[u][v] + times[1][cv]
                for (u, cu), (v, cv) in itertools.product(joins, joins) if v in along[u]),
               default=np.inf)
    return float(min(best, times[0][b]))
