"""Write a topology into PostGIS in one transaction, fast enough for city-sized extracts.

Node ids are reserved from the sequence up front so segments can reference them in the same
COPY stream; segments go through a temporary staging table so ``length_m`` is computed by
PostGIS from geography (``ST_Length(geom::geography)``), the one definition of length used
everywhere, and the change trigger fires once per table, not once per row.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterable

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.db.models import SLUG_RE
from app.errors import UserError
from ingest.network.model import FeatureLike, ImportSummary, NodePoint
from ingest.network.noding import Topology, build_topology
from ingest.network.properties import as_road_lines


class NetworkExistsError(UserError):
    """The network already has data and the caller did not ask to replace it."""


def _wkt_point(c: tuple[float, float]) -> str:
    return f"SRID=4326;POINT({c[0]!r} {c[1]!r})"


def _wkt_line(coords: list[tuple[float, float]]) -> str:
    return "SRID=4326;LINESTRING(" + ",".join(f"{x!r} {y!r}" for x, y in coords) + ")"


def _network_id(session: Session, network: str, replace: bool) -> int:
    if not re.match(SLUG_RE, network):
        raise UserError(f"network name {network[:80]!r} is not valid: use 1-64 lowercase "
                         "letters, digits, '-' or '_', starting with a letter or digit")
    row = session.execute(text("SELECT id FROM networks WHERE name = :n FOR UPDATE"),
                          {"n": network}).first()
    if row is None:
        return session.execute(text("INSERT INTO networks (name) VALUES (:n) RETURNING id"),
                               {"n": network}).scalar_one()
    has_data: bool = session.execute(text("SELECT EXISTS (SELECT 1 FROM road_segments "
                                    "WHERE network_id = :id)"), {"id": row.id}).scalar_one()
    if has_data and not replace:
        raise NetworkExistsError(f"network {network!r} already has segments; "
                                 "use replace to overwrite it")
    for table in ("segment_edits", "road_segments", "road_nodes"):
        session.execute(text(f"DELETE FROM {table} WHERE network_id = :id"), {"id": row.id})
    return row.id


def _copy_topology(session: Session, network_id: int, topo: Topology) -> None:
    conn = session.connection().connection.driver_connection
    assert conn is not None  # a live psycopg connection: COPY needs the driver's own API
    with conn.cursor() as cur:
        cur.execute("SELECT nextval(pg_get_serial_sequence('road_nodes', 'id')) "
                    "FROM generate_series(1, %s)", (len(topo.nodes),))
        ids = [r[0] for r in cur.fetchall()]
        with cur.copy("COPY road_nodes (id, network_id, geom, kind, traffic_light, external_id) "
                      "FROM STDIN") as copy:
            for node_id, node in zip(ids, topo.nodes, strict=True):
                copy.write_row((node_id, network_id, _wkt_point(node.coord), node.kind,
                                node.traffic_light, node.external_id))
        cur.execute("CREATE TEMP TABLE staging_segments (LIKE road_segments INCLUDING DEFAULTS) "
                    "ON COMMIT DROP")
        columns = ("network_id, source_node, target_node, geom, lanes_forward, lanes_backward, "
                   "speed_limit_kph, oneway, road_class, is_junction, name, surface, width_m, "
                   "external_id, attrs")
        with cur.copy(f"COPY staging_segments ({columns}, length_m) FROM STDIN") as copy:
            for seg in topo.segments:
                a = seg.attributes
                copy.write_row((network_id, ids[seg.source], ids[seg.target],
                                _wkt_line(seg.coords), a.lanes_forward, a.lanes_backward,
                                a.speed_limit_kph, a.oneway, a.road_class, a.is_junction,
                                a.name, a.surface, a.width_m, a.external_id,
                                json.dumps(a.attrs), 0))
        cur.execute(f"INSERT INTO road_segments ({columns}, length_m) "
                    f"SELECT {columns}, ST_Length(geom::geography) FROM staging_segments")
        cur.execute("DROP TABLE staging_segments")


def write_network(session: Session, network: str, lines: Iterable[FeatureLike], *,
                  replace: bool = False, node_crossings: bool = True,
                  node_points: Iterable[NodePoint] = (),
                  progress: Callable[[str], None] | None = None) -> ImportSummary:
    """Node ``lines`` into a topology and store it as network ``network``.

    ``node_crossings=False`` trusts the input's own topology (OSM shared nodes, our exports):
    lines then connect only where they share a vertex. The caller owns the transaction.
    ``progress`` is called with "node" and "store" as those stages finish.
    """
    road_lines = [part for feature in lines for part in as_road_lines(feature)]
    topo = build_topology(road_lines, crossings=node_crossings, node_points=node_points)
    if progress:
        progress("node")
    network_id = _network_id(session, network, replace)
    if topo.segments:
        _copy_topology(session, network_id, topo)
    if progress:
        progress("store")
    total: float = session.execute(text("SELECT COALESCE(sum(length_m), 0) FROM road_segments "
                                 "WHERE network_id = :id"), {"id": network_id}).scalar_one()
    return ImportSummary(network=network, network_id=network_id, segments=len(topo.segments),
                         nodes=len(topo.nodes), total_length_m=float(total),
                         lines_read=len(road_lines), duplicates_dropped=topo.duplicates_dropped,
                         crossings_noded=topo.crossings_noded)
