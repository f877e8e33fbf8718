"""Which OGC API collections exist: one ``{network}-segments``, one ``{network}-nodes`` and
one ``{network}-lanes`` (the lane boundaries ``ugvmap ingest lanes`` stored, each with the
lanes of the range of its segment it bounds) collection per network, resolved from the id in
the URL, and their GeoJSON features.

All SQL here takes user input only as bound parameters; column lists are constants.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from datetime import datetime
from typing import Any, Literal

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.db.models import SLUG_RE
from app.errors import NotFoundError

Kind = Literal["segments", "nodes", "lanes"]
KINDS: tuple[Kind, ...] = ("segments", "nodes", "lanes")
TABLES: dict[Kind, str] = {"segments": "road_segments", "nodes": "road_nodes",
                           "lanes": "lane_boundaries"}

# Editable segment attributes, in the order they are shown.
SEGMENT_ATTRIBUTES = ("lanes_forward", "lanes_backward", "speed_limit_kph", "oneway",
                      "road_class", "is_junction", "name", "surface", "width_m", "external_id",
                      "attrs")
# ``confidence`` is written by road extraction only: edits cannot set it (422 read-only).
SEGMENT_READONLY = ("source_node", "target_node", "length_m", "version", "updated_at",
                    "updated_by", "confidence")
# Columns of a segment feature before its geometry; ``segment_id`` repeats the feature id as a
# property, since clients that read GeoJSON through OGR (QGIS, GDAL) turn the id into their
# internal feature id and show it nowhere.
SEGMENT_COLUMNS = ", ".join(("id", "id AS segment_id", *SEGMENT_READONLY, *SEGMENT_ATTRIBUTES))
# Segment ends at node ``n`` (a loop counts twice), and the node kind a ``degree`` implies:
# the one rule the API, deletions and ``ugvmap network validate`` share.
NODE_DEGREE = ("(SELECT count(*) FROM road_segments s WHERE s.source_node = n.id) + "
               "(SELECT count(*) FROM road_segments s WHERE s.target_node = n.id)")
KIND_OF_DEGREE = ("CASE WHEN degree >= 3 THEN 'junction' WHEN degree = 1 THEN 'endpoint' "
                  "ELSE 'node' END")
NODE_ENDS = f"SELECT n.id, {NODE_DEGREE} AS degree FROM road_nodes n WHERE n.id = ANY(:ids)"
# Editable node attributes; ``kind`` and ``degree`` follow from the segments.
NODE_ATTRIBUTES = ("traffic_light", "external_id")
NODE_COLUMNS = ("id, id AS node_id, kind, traffic_light, external_id, version, updated_at, "
                f"updated_by, {NODE_DEGREE} AS degree")
# A boundary's row, then the lanes of the range of its segment it lies in (by its middle
# station): what the boundary separates, without a second request.
LANE_RANGE = ("(SELECT {col} FROM segment_lanes l WHERE l.segment_id = b.segment_id AND "
              "(b.station_from_m + b.station_to_m) / 2 BETWEEN l.station_from_m AND "
              "l.station_to_m ORDER BY l.station_from_m LIMIT 1)")
LANE_COLUMNS = ", ".join((
    "id", "id AS boundary_id", "segment_id", "kind", "colour", "width_m", "confidence",
    "position", "offset_m", "station_from_m", "station_to_m", "source", "version",
    "updated_at", "updated_by",
    *(f"{LANE_RANGE.format(col=col)} AS {name}" for col, name in (
        ("l.lanes_forward", "lanes_forward"), ("l.lanes_backward", "lanes_backward"),
        ("array_to_string(l.widths_m, ',')", "lane_widths_m")))))
# Editable lane boundary attributes (its geometry too).
LANE_ATTRIBUTES = ("kind", "colour", "width_m", "position", "source")
GEOMETRY = "ST_AsGeoJSON(geom, 15)"


@dataclass(frozen=True)
class Collection:
    """An OGC API collection: one network's segments, nodes or lane boundaries."""
    network: str
    network_id: int
    kind: Kind
    title: str | None = None

    @property
    def id(self) -> str:
        """The collection id clients use: ``{network}-{kind}``."""
        return f"{self.network}-{self.kind}"

    @property
    def table(self) -> str:
        """The table the collection's features live in."""
        return TABLES[self.kind]

    def select(self, geometry: str = GEOMETRY) -> str:
        """``SELECT`` list and table of its features, the geometry as ``geometry`` (SQL of
        GeoJSON text, e.g. reprojected for Part 2)."""
        if self.kind == "segments":
            return f"{SEGMENT_COLUMNS}, {geometry} AS geometry FROM road_segments"
        if self.kind == "lanes":
            return f"{LANE_COLUMNS}, {geometry} AS geometry FROM lane_boundaries b"
        return f"{NODE_COLUMNS}, {geometry} AS geometry FROM road_nodes n"


def list_collections(session: Session) -> list[Collection]:
    """The collections of every network, in name order so listings are stable."""
    rows = session.execute(text("SELECT id, name, title FROM networks ORDER BY name")).all()
    return [Collection(r.name, r.id, kind, r.title) for r in rows for kind in KINDS]


def network_row(session: Session, name: str) -> Any:
    """(id, title, version, created_at) of a network, or None; names that cannot exist (not a
    slug, e.g. with NUL bytes PostgreSQL would reject) are not even looked up."""
    if not re.fullmatch(SLUG_RE.strip("^$"), name):
        return None
    return session.execute(
        text("SELECT id, title, version, created_at FROM networks WHERE name = :n"),
        {"n": name}).first()


def resolve(session: Session, collection_id: str) -> Collection:
    """``{network}-segments`` / ``-nodes`` / ``-lanes`` -> Collection, or 404."""
    network, _, kind = collection_id.rpartition("-")
    if kind in KINDS and network:
        row = network_row(session, network)
        if row is not None:
            return Collection(network, row.id, kind, row.title)
    raise NotFoundError(f"collection {collection_id[:100]!r} not found")


@dataclass(frozen=True)
class Extent:
    """Where and (for segments) when a collection's features are: the lon/lat box and the
    range of ``updated_at``, each None when there is nothing to bound."""

    bbox: list[float] | None
    updated: tuple[datetime, datetime] | None


def extent(session: Session, collection: Collection) -> Extent:
    """The collection's extent in one query."""
    times = ("min(updated_at) AS t0, max(updated_at) AS t1" if collection.kind != "nodes"
             else "NULL::timestamptz AS t0, NULL::timestamptz AS t1")
    row = session.execute(text(
        f"SELECT ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e), t0, t1 FROM "
        f"(SELECT ST_Extent(geom) AS e, {times} "
        f"FROM {collection.table} WHERE network_id = :n) q"),
        {"n": collection.network_id}).one()
    bbox = None if row[0] is None else [float(v) for v in row[:4]]
    return Extent(bbox, None if row[4] is None else (row[4], row[5]))


def to_feature(row: Any) -> dict[str, Any]:
    """A result row (with ``id`` and ``geometry`` JSON text) -> GeoJSON Feature."""
    props = dict(row._mapping)
    fid, geometry = props.pop("id"), props.pop("geometry")
    if props.get("updated_at") is not None:
        props["updated_at"] = props["updated_at"].isoformat()
    return {"type": "Feature", "id": fid, "geometry": json.loads(geometry), "properties": props}


@dataclass(frozen=True)
class ItemQuery:
    """What a page of items is filtered by: a lon/lat box (``minx > maxx`` crosses the
    antimeridian), an ``updated_at`` interval (segments only; None ends are open) and
    equality on property columns (names from the property table, never from the client)."""

    bbox: tuple[float, float, float, float] | None = None
    updated_from: datetime | None = None
    updated_to: datetime | None = None
    equals: tuple[tuple[str, Any], ...] = ()
    bbox_srid: int = 4326
    """SRID of ``bbox`` (Part 2's ``bbox-crs``): 4326 for lon/lat, else projected metres."""


def _envelope(minx: str, maxx: str) -> str:
    return f"ST_Intersects(geom, ST_MakeEnvelope({minx}, :miny, {maxx}, :maxy, 4326))"


# A projected box becomes a lon/lat polygon before it meets the (indexed) lon/lat geometries;
# its edges are cut into this many pieces first, so a UTM box's curved edges stay faithful.
PROJECTED_BOX_PIECES = 64
PROJECTED_BOX = ("ST_Intersects(geom, ST_Transform(ST_Segmentize(ST_MakeEnvelope("
                 ":minx, :miny, :maxx, :maxy, :srid), :piece), 4326))")


def _where(collection: Collection, query: ItemQuery) -> tuple[str, dict[str, Any]]:
    """SQL condition and parameters; ``ST_Intersects`` so a line whose box meets the bbox
    but whose shape does not is left out, as the standard's "intersects" asks."""
    clauses = ["network_id = :network_id"]
    params: dict[str, Any] = {"network_id": collection.network_id}
    if query.bbox:
        minx, miny, maxx, maxy = query.bbox
        params.update(minx=minx, miny=miny, maxx=maxx, maxy=maxy)
        if query.bbox_srid != 4326:
            clauses.append(PROJECTED_BOX)
            params.update(srid=query.bbox_srid, piece=max(maxx - minx, maxy - miny, 1e-3)
                          / PROJECTED_BOX_PIECES)
        elif minx <= maxx:
            clauses.append(_envelope(":minx", ":maxx"))
        else:  # across the antimeridian: the part east of minx and the part west of maxx
            clauses.append(f"({_envelope(':minx', '180')} OR {_envelope('-180', ':maxx')})")
    if collection.kind != "nodes":
        if query.updated_from is not None:
            clauses.append("updated_at >= :updated_from")
            params["updated_from"] = query.updated_from
        if query.updated_to is not None:
            clauses.append("updated_at <= :updated_to")
            params["updated_to"] = query.updated_to
    for i, (column, value) in enumerate(query.equals):
        clauses.append(f"{column} = :eq{i}")
        params[f"eq{i}"] = value
    return " AND ".join(clauses), params


def query_items(session: Session, collection: Collection, query: ItemQuery, *,
                limit: int, offset: int, geometry: str = GEOMETRY
                ) -> tuple[int, list[dict[str, Any]]]:
    """(numberMatched, features) for one page, ordered by id so paging is stable; the
    geometries as the SQL ``geometry`` makes them (see :meth:`Collection.select`)."""
    where, params = _where(collection, query)
    matched: int = session.execute(text(f"SELECT count(*) FROM {collection.table} WHERE {where}"),
                              params).scalar_one()
    rows = session.execute(text(
        f"SELECT {collection.select(geometry)} WHERE {where} "
        "ORDER BY id LIMIT :limit OFFSET :offset"),
        {**params, "limit": limit, "offset": offset}).all()
    return matched, [to_feature(r) for r in rows]


def get_item(session: Session, collection: Collection, fid: int, *,
             for_update: bool = False, geometry: str = GEOMETRY) -> dict[str, Any]:
    """One feature as GeoJSON (404 if it is not in this collection); ``for_update`` locks its row
    for an edit in the same transaction."""
    lock = " FOR UPDATE" if for_update else ""
    row = session.execute(text(
        f"SELECT {collection.select(geometry)} "
        f"WHERE id = :id AND network_id = :network_id{lock}"),
        {"id": fid, "network_id": collection.network_id}).first()
    if row is None:
        raise NotFoundError(f"feature {fid} in {collection.id!r} not found")
    return to_feature(row)


def settle_nodes(session: Session, node_ids: list[int]) -> None:
    """After segments were added or removed at these nodes: delete the ones left without a
    segment and give the others the kind their degree implies (what ``ugvmap network
    validate`` checks). A node's version is not bumped: it counts edits of the node itself,
    while its kind and degree follow its segments."""
    ends = {"ids": sorted(set(node_ids))}
    session.execute(text(f"DELETE FROM road_nodes WHERE id IN (SELECT id FROM ({NODE_ENDS}) d "
                         "WHERE degree = 0)"), ends)
    session.execute(text(f"UPDATE road_nodes n SET kind = {KIND_OF_DEGREE} FROM ({NODE_ENDS}) d "
                         f"WHERE n.id = d.id AND n.kind <> {KIND_OF_DEGREE}"), ends)
