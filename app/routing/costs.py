"""Edge costs: how long a segment takes to drive and how far it is.

The same speed table is rendered as SQL so that the pgRouting oracle test and the benchmark
price edges exactly like the in-memory graph does; two copies of the table would drift.
"""

from __future__ import annotations

from collections.abc import Collection
from enum import StrEnum

import numpy as np

from app.routing.profiles import DEFAULT


class Cost(StrEnum):
    """What a route minimises (OSRM's ``weight_name``)."""

    TIME = "time"
    DISTANCE = "distance"


# Speed assumed where a segment has no speed limit, by road class (km/h). The keys are the OSM
# highway values the importer writes; anything else drives at FALLBACK_SPEED_KPH.
DEFAULT_SPEED_KPH: dict[str, float] = {
    "motorway": 100.0, "motorway_link": 60.0, "trunk": 80.0, "trunk_link": 50.0,
    "primary": 60.0, "primary_link": 40.0, "secondary": 50.0, "secondary_link": 40.0,
    "tertiary": 40.0, "tertiary_link": 30.0, "unclassified": 30.0, "residential": 30.0,
    "living_street": 10.0, "service": 15.0, "track": 15.0, "road": 30.0,
}
FALLBACK_SPEED_KPH = 30.0


def effective_speed_kph(speed_limit: np.ndarray, road_class: np.ndarray) -> np.ndarray:
    """Speed limit where known (non-NaN), else the road class default."""
    classes, inverse = np.unique(road_class.astype(str), return_inverse=True)
    defaults = np.array([DEFAULT_SPEED_KPH.get(c, FALLBACK_SPEED_KPH) for c in classes],
                        dtype=np.float64)[inverse.reshape(-1)]
    return np.where(np.isnan(speed_limit), defaults, speed_limit)


def segment_costs(cost: Cost, length_m: np.ndarray, speed_kph: np.ndarray) -> np.ndarray:
    """Cost of traversing each whole segment: metres, or seconds at the effective speed."""
    if cost is Cost.DISTANCE:
        return length_m.astype(np.float64, copy=True)
    return length_m / (speed_kph / 3.6)


def speed_sql(table: str = "road_segments") -> str:
    """SQL expression for the effective speed (km/h) of a row of ``table``."""
    cases = " ".join(f"WHEN '{cls}' THEN {kph}" for cls, kph in DEFAULT_SPEED_KPH.items())
    return (f"COALESCE({table}.speed_limit_kph, "
            f"CASE {table}.road_class {cases} ELSE {FALLBACK_SPEED_KPH} END)")


def cost_sql(cost: Cost, table: str = "road_segments") -> str:
    """SQL expression for a whole segment's cost, identical to :func:`segment_costs`."""
    if cost is Cost.DISTANCE:
        return f"{table}.length_m"
    return f"{table}.length_m / ({speed_sql(table)} / 3.6)"


def pgrouting_edges_sql(network_id: int, cost: Cost,
                        avoid: Collection[str] = DEFAULT.forbidden) -> str:
    """pgRouting edge query pricing segments like the graph does (-1 against a one-way, and
    both ways on the ``avoid`` classes: by default those the default vehicle never drives).

    The oracle test and the benchmark hand this to ``pgr_dijkstra``.
    """
    c = cost_sql(cost)
    banned = (f"road_class IN ({', '.join(repr(str(a)) for a in sorted(avoid))}) OR "
              if avoid else "")
    return (f"SELECT id, source_node AS source, target_node AS target, "
            f"CASE WHEN {banned}oneway = 'backward' THEN -1 ELSE {c} END AS cost, "
            f"CASE WHEN {banned}oneway = 'forward' THEN -1 ELSE {c} END AS reverse_cost "
            f"FROM road_segments WHERE network_id = {int(network_id)}")
