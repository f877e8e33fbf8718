"""Synthetic road networks with known answers, for tests and benchmarks.

Written straight into the schema with SQL (``generate_series``), so a 100k-segment grid takes
seconds; nodes are shared by exact coordinates as an importer would share them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import psycopg

from app.network.segment_rows import insert_segments

METRES_PER_DEG_LAT = 111_320.0


def _one(cursor: psycopg.Cursor) -> int:
    """The single value a ``RETURNING id`` statement gives back."""
    row = cursor.fetchone()
    assert row is not None
    return int(row[0])


def create_network(conn: psycopg.Connection, name: str) -> int:
    """A new, empty network row; returns its id."""
    return _one(conn.execute("INSERT INTO networks (name) VALUES (%s) RETURNING id", (name,)))


def node_at(conn: psycopg.Connection, network_id: int, lon: float, lat: float) -> int:
    """The node at exactly (lon, lat), created if needed."""
    row = conn.execute(
        "SELECT id FROM road_nodes WHERE network_id = %s AND "
        "geom = ST_SetSRID(ST_MakePoint(%s, %s), 4326)", (network_id, lon, lat)).fetchone()
    if row:
        return row[0]
    return _one(conn.execute(
        "INSERT INTO road_nodes (network_id, geom) VALUES "
        "(%s, ST_SetSRID(ST_MakePoint(%s, %s), 4326)) RETURNING id",
        (network_id, lon, lat)))


def add_line(conn: psycopg.Connection, network_id: int, coords: Sequence[Sequence[float]],
             **attrs: object) -> int:
    """Insert one segment along ``coords`` (source = first point); returns its id.

    ``attrs`` are road_segments columns (oneway, speed_limit_kph, road_class, lanes_forward...).
    The length is the geodesic length of the line.
    """
    src = node_at(conn, network_id, *coords[0])
    dst = node_at(conn, network_id, *coords[-1])
    wkt = "LINESTRING(" + ", ".join(f"{float(x)!r} {float(y)!r}" for x, y in coords) + ")"
    return _one(conn.execute(insert_segments(
        {"network_id": "%s", "source_node": "%s", "target_node": "%s", "geom": "g",
         **dict.fromkeys(attrs, "%s")}, "ST_GeomFromText(%s, 4326) AS g", returning=True),
        (network_id, src, dst, *attrs.values(), wkt)))


def grid(conn: psycopg.Connection, name: str, rows: int, cols: int, *,
         origin: tuple[float, float] = (1.5, 42.5), spacing_m: float = 100.0,
         seed: float | None = 0.42) -> int:
    """A rows×cols lattice of two-way streets ``spacing_m`` apart; returns the network id.

    With a ``seed``, speed limits are drawn from 20..70 km/h so that time and distance
    routes differ; node (r, c) has ``external_id`` ``'r:c'``.
    """
    net = create_network(conn, name)
    dlat = spacing_m / METRES_PER_DEG_LAT
    dlon = spacing_m / (METRES_PER_DEG_LAT * math.cos(math.radians(origin[1])))
    if seed is not None:
        conn.execute("SELECT setseed(%s)", (seed,))
    speed = "20 + 10 * floor(random() * 6)" if seed is not None else "NULL"
    segments = insert_segments({"network_id": "%(net)s", "source_node": "s", "target_node": "t",
                                "geom": "geom", "speed_limit_kph": speed,
                                "road_class": "'residential'"}, "e ORDER BY s, t")
    conn.execute(f"""
        WITH n AS (
            INSERT INTO road_nodes (network_id, geom, external_id)
            SELECT %(net)s, ST_SetSRID(ST_MakePoint(%(lon)s + c * %(dlon)s,
                                                    %(lat)s + r * %(dlat)s), 4326), r || ':' || c
              FROM generate_series(0, %(rows)s - 1) r, generate_series(0, %(cols)s - 1) c
            RETURNING id, geom, external_id),
        g AS (SELECT id, geom, split_part(external_id, ':', 1)::int AS r,
                     split_part(external_id, ':', 2)::int AS c FROM n),
        e AS (SELECT a.id AS s, b.id AS t, ST_MakeLine(a.geom, b.geom) AS geom
                FROM g a JOIN g b ON b.r = a.r AND b.c = a.c + 1
              UNION ALL
              SELECT a.id, b.id, ST_MakeLine(a.geom, b.geom)
                FROM g a JOIN g b ON b.r = a.r + 1 AND b.c = a.c)
        {segments}
    """, {"net": net, "lon": origin[0], "lat": origin[1], "dlon": dlon, "dlat": dlat,
          "rows": rows, "cols": cols})
    return net
