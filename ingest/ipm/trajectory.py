"""The path the vehicle drove while recording an ``ipm-mosaic`` layer (``layer_trajectories``).

``ugvmap ingest ipm`` knows where every frame was taken; the poses of the frames it used, in
time order, are the drive's trajectory. It is stored with the layer, one row per drive (named
by the frames' path, so ingesting the same drive again replaces its row; the rows go with the
layer when it is deleted), in the same transaction that registers the drive's zones, so a layer
never has zones without their drive or the other way round. Road extraction on the layer uses
it as a road sample nobody had to draw: the vehicle drove there
(:func:`ingest.roads.layer.ingest_layer_roads`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np
import shapely
from pyproj import Geod
from sqlalchemy import text
from sqlalchemy.orm import Session

from ingest.ipm.poses import Pose


def trajectory_line(poses: Sequence[Pose]) -> shapely.LineString | None:
    """The lon/lat polyline through ``poses`` in time order, repeated positions dropped (a
    vehicle standing still); None when it never moved (no line to store)."""
    ordered = sorted(poses, key=lambda p: p.t)
    xy = np.array([(p.lon, p.lat) for p in ordered], float).reshape(-1, 2)
    if len(xy):
        xy = xy[np.r_[True, np.any(np.diff(xy, axis=0) != 0, axis=1)]]
    return shapely.LineString(xy) if len(xy) >= 2 else None


def geodesic_length_m(line: shapely.LineString) -> float:
    """Length of a lon/lat line on the WGS84 ellipsoid, metres."""
    return float(Geod(ellps="WGS84").geometry_length(line))


def store_trajectory(session: Session, layer: str, name: str, line: shapely.LineString,
                     meta: dict) -> None:
    """Store (or replace) drive ``name``'s trajectory on layer ``layer``, in the caller's
    transaction (the layer row must exist in it)."""
    layer_id: int = session.execute(text("SELECT id FROM layers WHERE slug = :s"),
                               {"s": layer}).scalar_one()
    session.execute(text("DELETE FROM layer_trajectories WHERE layer_id = :l AND name = :n"),
                    {"l": layer_id, "n": name})
    session.execute(text(
        "INSERT INTO layer_trajectories (layer_id, name, geom, meta) VALUES "
        "(:l, :n, ST_GeomFromWKB(:wkb, 4326), CAST(:meta AS jsonb))"),
        {"l": layer_id, "n": name, "wkb": shapely.to_wkb(line),
         "meta": json.dumps({**meta, "length_m": round(geodesic_length_m(line), 2)})})


def layer_trajectories(session: Session, layer: str) -> list[shapely.LineString]:
    """Every stored drive of layer ``layer`` (lon/lat), oldest first."""
    rows: Sequence[bytes] = session.execute(text(
        "SELECT ST_AsBinary(t.geom) FROM layer_trajectories t JOIN layers l ON l.id = t.layer_id "
        "WHERE l.slug = :s ORDER BY t.created_at, t.id"), {"s": layer}).scalars().all()
    return [shapely.from_wkb(bytes(wkb)) for wkb in rows]
