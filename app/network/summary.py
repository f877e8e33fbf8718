"""What a network holds, in a few numbers: the one query that lists networks (``GET /networks``
and ``ugvmap network list`` answer the same rows) and the ranges of its tiles' integer fields
(the ``tilestats`` of the metadata a vector-tile package or GDAL reads).
"""

from __future__ import annotations

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.network import tilejson as tj
from app.network.properties import by_name

NETWORKS_SQL = """
SELECT n.id, n.name, n.title, n.description, n.version, n.updated_at,
       (SELECT count(*) FROM road_segments s WHERE s.network_id = n.id) AS segments,
       (SELECT count(*) FROM road_nodes r WHERE r.network_id = n.id) AS nodes,
       ST_XMin(b.e), ST_YMin(b.e), ST_XMax(b.e), ST_YMax(b.e), n.created_at
  FROM networks n,
       LATERAL (SELECT ST_Extent(geom) AS e FROM road_segments s
                 WHERE s.network_id = n.id) b
 WHERE CAST(:name AS text) IS NULL OR n.name = CAST(:name AS text)
 ORDER BY n.name
"""


def integer_ranges(session: Session, network_id: int) -> dict[str, tuple[int, int]]:
    """Min and max of the integer fields of the network's vector tiles (for ``tilestats``)."""
    props = by_name("segments")
    fields = [f for layer in tj.TILE_LAYERS if layer.kind == "segments"
              for f in layer.fields if props[f].type == "integer"]
    if not fields:
        return {}
    row = session.execute(text(
        "SELECT " + ", ".join(f"min({f}), max({f})" for f in fields)
        + " FROM road_segments WHERE network_id = :n"), {"n": network_id}).one()
    if row[0] is None:
        return {}
    return {f: (int(row[2 * i]), int(row[2 * i + 1])) for i, f in enumerate(fields)}
