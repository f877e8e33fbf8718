"""The network as the Lanelet2 export reads it: column arrays in segment-id order.

Read straight into numpy (geometry as WKB, decoded by shapely in bulk) in chunks, so a
million segments never exist as Python row objects, then projected once into the map's
metric frame. Tests build the same tables from plain lists.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import shapely
from sqlalchemy import Connection, text

from app.db.session import get_engine
from app.errors import UserError
from app.routing.splice import ragged_take

SEGMENT_SQL = """
SELECT s.id, s.source_node, s.target_node, s.length_m, s.lanes_forward, s.lanes_backward,
       s.oneway, s.speed_limit_kph, s.road_class, s.name, s.width_m, ST_AsBinary(s.geom)
  FROM road_segments s
 WHERE s.network_id = :network_id {where}
 ORDER BY s.id
"""
# By the GiST index (network_id + 0: see app.routing.live.read_segments for why).
AREA_WHERE = "AND ST_Intersects(s.geom, ST_MakeEnvelope(:w, :s, :e, :n, 4326))"
BBOX_WHERE = f"AND s.network_id + 0 = :network_id {AREA_WHERE}"
NODE_SQL = """
SELECT n.id, ST_X(n.geom), ST_Y(n.geom), n.traffic_light
  FROM road_nodes n
 WHERE n.network_id = :network_id {where}
 ORDER BY n.id
"""
NODE_IDS_WHERE = "AND n.id = ANY(CAST(:ids AS bigint[]))"
BOUNDS_SQL = """
SELECT segment_id, position, kind, colour, width_m, confidence, station_from_m, station_to_m,
       source, offset_m, ST_AsBinary(geom)
  FROM lane_boundaries WHERE network_id = :network_id
 ORDER BY segment_id, station_from_m, id
"""
RANGES_SQL = """
SELECT segment_id, station_from_m, station_to_m, lanes_forward, lanes_backward, widths_m,
       offsets_m
  FROM segment_lanes WHERE network_id = :network_id
 ORDER BY segment_id, station_from_m
"""
CHUNK = 50_000
COLUMNS = ("ids", "source", "target", "length_m", "lanes_forward", "lanes_backward", "oneway",
           "speed_limit_kph", "road_class", "name", "width_m")
"""The per-segment columns of a :class:`RoadTable` (besides its ragged vertices)."""


@dataclass
class RoadTable:
    """Segments to map, one entry per segment, ordered by id (the export's determinism)."""

    ids: np.ndarray
    source: np.ndarray
    target: np.ndarray
    lonlat: np.ndarray  # (V, 2) every vertex, flat
    offsets: np.ndarray  # (S + 1) where each segment's vertices start
    length_m: np.ndarray
    lanes_forward: np.ndarray
    lanes_backward: np.ndarray
    oneway: np.ndarray  # str: none / forward / backward
    speed_limit_kph: np.ndarray  # NaN where unknown
    road_class: np.ndarray  # str
    name: np.ndarray  # str or None
    width_m: np.ndarray  # NaN where unknown

    def __len__(self) -> int:
        return len(self.ids)

    def take(self, rows: np.ndarray) -> tuple[RoadTable, np.ndarray]:
        """The segments ``rows``, in that order, and where their vertices were in ``lonlat``
        (to take any per-vertex array along with them)."""
        offsets, gather = ragged_take(self.offsets, rows)
        return RoadTable(**{name: getattr(self, name)[rows] for name in COLUMNS},
                         lonlat=self.lonlat[gather], offsets=offsets), gather


@dataclass
class NodeTable:
    """The nodes the segments end at, ordered by id."""

    ids: np.ndarray
    lonlat: np.ndarray
    traffic_light: np.ndarray


@dataclass
class StoredBound:
    """A ``lane_boundaries`` row as the export reads it."""

    position: int | None
    kind: str
    colour: str
    width_m: float | None
    confidence: float
    station_from_m: float
    station_to_m: float
    source: str
    offset_m: float
    lonlat: np.ndarray


@dataclass
class StoredLanes:
    """A segment's ``segment_lanes`` ranges and ``lane_boundaries`` rows."""

    ranges: list[tuple[float, float, int, int]] = field(default_factory=list)
    widths: list[float] = field(default_factory=list)
    """Each range's road width (its lanes' widths summed)."""
    offsets: list[list[float]] = field(default_factory=list)
    """Each range's boundary offsets, right to left (+ left of the segment)."""
    bounds: list[StoredBound] = field(default_factory=list)


def read_paint(conn: Connection, network_id: int, segment_ids: np.ndarray
               ) -> dict[int, StoredLanes]:
    """The stored lanes of the segments among ``segment_ids`` that have them. Read by
    network (its index), not by a list of every exported segment's id: a country's export
    would send a million ids for the few roads that have paint."""
    wanted = set(segment_ids.tolist())
    out: dict[int, StoredLanes] = {}
    for r in conn.execute(text(RANGES_SQL), {"network_id": network_id}):
        if int(r.segment_id) not in wanted:
            continue
        lanes = out.setdefault(int(r.segment_id), StoredLanes())
        lanes.ranges.append((r.station_from_m, r.station_to_m, r.lanes_forward,
                             r.lanes_backward))
        lanes.widths.append(float(sum(r.widths_m)))
        lanes.offsets.append([float(o) for o in r.offsets_m])
    for r in conn.execute(text(BOUNDS_SQL), {"network_id": network_id}):
        if int(r[0]) in out:
            out[int(r[0])].bounds.append(StoredBound(
                r[1], r[2], r[3], r[4], r[5] or 0.0, r[6], r[7], r[8], r[9] or 0.0,
                shapely.get_coordinates(shapely.from_wkb(bytes(r[10])))))
    return out


@dataclass
class NetworkSelection:
    """What an export maps: the network's identity, its segments (all, or those meeting a
    bbox) and their nodes."""

    name: str
    version: int
    roads: RoadTable
    nodes: NodeTable
    bbox: tuple[float, float, float, float] | None = None
    notes: list[str] = field(default_factory=list)
    paint: dict[int, StoredLanes] = field(default_factory=dict)
    """The stored lanes of the segments that have them (``ugvmap ingest lanes``)."""


def _float(values: list[object]) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def road_table(rows: list[tuple]) -> RoadTable:
    """Rows of :data:`SEGMENT_SQL` (geometry as WKB or a shapely line) as a table."""
    cols: list[tuple] = list(zip(*rows, strict=True)) if rows else [() for _ in range(12)]
    geoms = [g if isinstance(g, shapely.Geometry) else shapely.from_wkb(bytes(g))
             for g in cols[11]]
    lonlat, index = shapely.get_coordinates(np.array(geoms, dtype=object), return_index=True)
    offsets = np.concatenate([[0], np.cumsum(np.bincount(index, minlength=len(geoms)))])
    return RoadTable(
        ids=np.array(cols[0], np.int64), source=np.array(cols[1], np.int64),
        target=np.array(cols[2], np.int64), lonlat=lonlat, offsets=offsets.astype(np.int64),
        length_m=_float(list(cols[3])), lanes_forward=np.array(cols[4], np.int64),
        lanes_backward=np.array(cols[5], np.int64), oneway=np.array(cols[6], dtype=object),
        speed_limit_kph=_float(list(cols[7])), road_class=np.array(cols[8], dtype=object),
        name=np.array(cols[9], dtype=object), width_m=_float(list(cols[10])))


def concat(tables: list[RoadTable]) -> RoadTable:
    """Tables read chunk by chunk, as one."""
    if len(tables) == 1:
        return tables[0]
    shift = np.cumsum([0] + [len(t.lonlat) for t in tables[:-1]])
    offsets = np.concatenate([[0]] + [t.offsets[1:] + s for t, s in zip(tables, shift,
                                                                        strict=True)])
    return RoadTable(
        **{name: np.concatenate([getattr(t, name) for t in tables]) for name in COLUMNS},
        lonlat=np.concatenate([t.lonlat for t in tables]), offsets=offsets)


def read_selection(conn: Connection, network: str,
                   bbox: tuple[float, float, float, float] | None = None) -> NetworkSelection:
    """Network ``network``'s segments (those meeting ``bbox`` when given, whole) and their
    end nodes. The caller's connection should be REPEATABLE READ, so the version read matches
    the rows."""
    row = conn.execute(text("SELECT id, version FROM networks WHERE name = :n"),
                       {"n": network}).first()
    if row is None:
        raise UserError(f"network {network[:100]!r} does not exist")
    params: dict[str, object] = {"network_id": row.id}
    where = ""
    if bbox is not None:
        where = BBOX_WHERE
        params.update(zip("wsen", bbox, strict=True))
    result = conn.execution_options(stream_results=True, yield_per=CHUNK).execute(
        text(SEGMENT_SQL.format(where=where)), params)
    tables = [road_table([tuple(r) for r in part]) for part in result.partitions(CHUNK)]
    roads = concat(tables) if tables else road_table([])
    ends = np.unique(np.concatenate([roads.source, roads.target]))
    node_rows = conn.execute(
        text(NODE_SQL.format(where=NODE_IDS_WHERE if bbox is not None else "")),
        {"network_id": row.id, "ids": ends.tolist()}).all()
    if bbox is None:  # every node of the network; keep those the segments end at
        wanted = set(ends.tolist())
        node_rows = [r for r in node_rows if r[0] in wanted]
    nodes = NodeTable(ids=np.array([r[0] for r in node_rows], np.int64),
                      lonlat=np.array([(r[1], r[2]) for r in node_rows],
                                      np.float64).reshape(-1, 2),
                      traffic_light=np.array([r[3] for r in node_rows], bool))
    return NetworkSelection(network, int(row.version), roads, nodes, bbox,
                            paint=read_paint(conn, row.id, roads.ids))


@contextmanager
def snapshot() -> Iterator[Connection]:
    """A read-only REPEATABLE READ transaction: one consistent view of the network (its
    version and rows) however long the export reads."""
    with get_engine().connect() as conn:
        conn.execution_options(isolation_level="REPEATABLE READ")
        with conn.begin():
            yield conn
