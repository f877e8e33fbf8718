"""The off-road cost surface of a vehicle on a height grid (pure functions).

Each cell's cost is the seconds a vehicle takes per metre there (1 / its speed on the cell's
slope); a cell it cannot drive (nodata, steeper than it climbs, a step higher than it
crosses, forbidden) costs infinity. ``skimage.graph.MCP_Geometric`` then charges a move
between neighbours the mean of the two cells' costs times the move's length (the cell size,
or its diagonal), so a path's cost is its driving time in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter

from app.routing.profiles import OffroadSettings
from app.terrain.relief import slope_degrees

#: Why a cell cannot be driven (the ``why`` grid), for the error a start there gets.
OK, NODATA, STEEP, STEP, FORBIDDEN = range(5)


@dataclass(frozen=True)
class CellCosts:
    """A vehicle's cost surface and what it was made from, cell by cell."""

    cost: np.ndarray  # float64 seconds per metre; inf where the vehicle cannot drive
    slope: np.ndarray  # float32 degrees (NaN on nodata)
    step: np.ndarray  # float32 metres: object height (DSM - DTM) or local relief
    why: np.ndarray  # uint8: OK, NODATA, STEEP, STEP or FORBIDDEN


def padded(grid: np.ndarray) -> np.ndarray:
    """``grid`` with a border of nodata (NaN), for the 3 x 3 windows of its edges."""
    return np.pad(grid.astype(np.float32), 1, constant_values=np.nan)


def local_step(heights: np.ndarray) -> np.ndarray:
    """A cell's height above or below the median of its 3 x 3 neighbourhood: 0 on any plane,
    the height of a boulder, a bank or a ditch one cell wide (NaN next to nodata)."""
    filled = np.where(np.isfinite(heights), heights, 0.0)
    median = median_filter(filled, size=3, mode="nearest")
    near_nodata = median_filter(np.isnan(heights).astype(np.uint8), size=3, mode="nearest")
    return np.where(near_nodata > 0, np.nan, np.abs(filled - median)).astype(np.float32)


def cell_costs(heights: np.ndarray, cell_m: float, settings: OffroadSettings,
               surface: np.ndarray | None = None,
               forbidden: np.ndarray | None = None) -> CellCosts:
    """The cost surface of ``heights`` (a DTM; NaN nodata) for a vehicle with ``settings``.

    ``surface``: the DSM on the same grid, whose height above the DTM is the step (trees,
    buildings, vehicles); else the DEM's local relief (:func:`local_step`). ``forbidden``:
    cells never driven (water, buildings).
    """
    slope = slope_degrees(padded(heights), cell_m)
    step = (np.abs(surface - heights).astype(np.float32) if surface is not None
            else local_step(heights))
    why = np.full(heights.shape, OK, np.uint8)
    why[~(step <= settings.max_step_m)] = STEP  # NaN step (no DSM there): not driven
    why[slope > settings.max_slope_deg] = STEEP
    if forbidden is not None:
        why[forbidden] = FORBIDDEN
    why[np.isnan(heights) | np.isnan(slope)] = NODATA
    speed_ms = settings.speed_kph(slope) / 3.6
    with np.errstate(divide="ignore"):
        cost = np.where((why == OK) & (speed_ms > 0), 1.0 / speed_ms, np.inf)
    return CellCosts(cost, slope, step, why)
