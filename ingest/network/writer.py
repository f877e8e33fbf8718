"""Write a topology into PostGIS in one transaction, streaming, for country-sized extracts.

The lines are read twice (see :class:`~ingest.network.noding.Noder`) in chunks of
:data:`CHUNK_LINES`; the second pass COPYs each chunk's segments into a temporary staging
table as soon as it is split, so memory holds one chunk of lines plus the compact vertex table,
never the whole network as Python objects. Node ids are reserved from the sequence chunk by
chunk so staged segments already carry them; nodes (whose kind needs their final degree) are
COPYed at the end, then one ``INSERT ... SELECT`` moves the segments in with ``length_m``
computed by PostGIS from geography (``ST_Length(geom::geography)``, the one definition of
length used everywhere).

Change notifications: the row triggers of migration ``0002`` would announce each bulk statement
with the extent of a million rows; the import sets ``ugvmap.bulk_load`` (migration
``0003_netscale`` makes the trigger skip while it is on) and bumps the network version once,
with no bounding box: listeners reload that network once instead of patching it repeatedly,
and rebuilds the network's low-zoom ``road_overview`` once.
"""

from __future__ import annotations

import itertools
import json
import re
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np
import shapely
from sqlalchemy import text
from sqlalchemy.orm import Session

from app.db.models import SLUG_RE
from app.errors import UserError
from app.network.segment_rows import insert_segments
from ingest.network import noding
from ingest.network.model import FeatureLike, ImportSummary, NodePoint, RoadLine
from ingest.network.noding import Noder, node_kind
from ingest.network.properties import as_road_lines

CHUNK_LINES = 20_000
# Shares of the progress bar: pass 1 (read), pass 2 (split + stage), then the final inserts.
READ_SHARE, SPLIT_SHARE = 0.3, 0.55

Progress = Callable[[str, float], None]
"""``progress(message, fraction)``: what the import is doing and how far it is (0..1)."""

Read = Callable[[], Iterable[RoadLine | NodePoint]]
"""Returns a fresh iterator over the same lines (and node points) on every call."""

SEGMENT_COLUMNS = ("network_id, source_node, target_node, geom, lanes_forward, lanes_backward, "
                   "speed_limit_kph, oneway, road_class, is_junction, name, surface, width_m, "
                   "external_id, attrs, confidence")


class NetworkExistsError(UserError):
    """The network already has data and the caller did not ask to replace it."""


class NoLinesError(UserError):
    """The input holds no road line."""


def lock_network(session: Session, network: str) -> int:
    """The id of network ``network``, its row locked for the caller's transaction; a new name
    is checked and created (empty)."""
    if not re.match(SLUG_RE, network):
        raise UserError(f"network name {network[:80]!r} is not valid: use 1-64 lowercase "
                        "letters, digits, '-' or '_', starting with a letter or digit")
    row = session.execute(text("SELECT id FROM networks WHERE name = :n FOR UPDATE"),
                          {"n": network}).first()
    if row is None:
        return session.execute(text("INSERT INTO networks (name) VALUES (:n) RETURNING id"),
                               {"n": network}).scalar_one()
    return int(row.id)


def _network_id(session: Session, network: str, replace: bool) -> int:
    network_id = lock_network(session, network)
    has_data: bool = session.execute(text("SELECT EXISTS (SELECT 1 FROM road_segments "
                                    "WHERE network_id = :id)"), {"id": network_id}).scalar_one()
    if has_data and not replace:
        raise NetworkExistsError(f"network {network!r} already has segments; replace them "
                                 "with --replace (POST /jobs: \"replace\": true)")
    # A reviewer's deletion of an extracted segment stays: it is what the next extraction of
    # that layer learns "not road" from (ingest/roads/review.py), and re-extracting the
    # network in place is exactly when it is needed.
    session.execute(text(
        "DELETE FROM segment_edits WHERE network_id = :id "
        "AND NOT (action = 'delete' AND old->'attrs' ? 'extracted_from')"), {"id": network_id})
    for table in ("road_segments", "road_nodes"):
        session.execute(text(f"DELETE FROM {table} WHERE network_id = :id"), {"id": network_id})
    return network_id


def _chunked(items: Iterable[RoadLine | NodePoint]
             ) -> Iterator[tuple[list[RoadLine], list[NodePoint]]]:
    lines: list[RoadLine] = []
    points: list[NodePoint] = []
    for item in items:
        if isinstance(item, NodePoint):
            points.append(item)
        else:
            lines.append(item)
        if len(lines) == CHUNK_LINES:
            yield lines, points
            lines, points = [], []
    if lines or points:
        yield lines, points


def _ewkb(coords: np.ndarray, offsets: np.ndarray | None = None) -> list[str]:
    """Hex EWKB (SRID 4326) of points, or of lines split at ``offsets``: what COPY takes for
    a geometry column, built vectorised instead of one WKT string per row."""
    if offsets is None:
        geoms = shapely.points(coords)
    else:
        geoms = shapely.linestrings(coords, indices=np.repeat(np.arange(len(offsets) - 1),
                                                              np.diff(offsets)))
    return shapely.to_wkb(shapely.set_srid(geoms, 4326), hex=True, include_srid=True).tolist()


class _Stager:
    """The raw-connection side of one import: node id reservation and COPY streams."""

    def __init__(self, session: Session, network_id: int) -> None:
        conn = session.connection().connection.driver_connection
        assert conn is not None  # a live psycopg connection: COPY needs the driver's own API
        self.conn = conn
        self.network_id = network_id
        self.node_ids = np.zeros(0, np.int64)
        with self.conn.cursor() as cur:
            cur.execute("CREATE TEMP TABLE staging_segments "
                        "(LIKE road_segments INCLUDING DEFAULTS) ON COMMIT DROP")

    def reserve(self, node_count: int) -> None:
        """Sequence ids for the nodes numbered since the last call."""
        more = node_count - len(self.node_ids)
        if more:
            with self.conn.cursor() as cur:
                cur.execute("SELECT nextval(pg_get_serial_sequence('road_nodes', 'id')) "
                            "FROM generate_series(1, %s)", (more,))
                fresh = np.array([r[0] for r in cur.fetchall()], np.int64)
            self.node_ids = np.concatenate([self.node_ids, fresh])

    def segments(self, chunk: Any) -> None:
        if not len(chunk):
            return
        geoms = _ewkb(chunk.coords, chunk.offsets)
        src = self.node_ids[chunk.source].tolist()
        dst = self.node_ids[chunk.target].tolist()
        attrs_json: dict[int, str] = {}
        with self.conn.cursor() as cur, cur.copy(
                f"COPY staging_segments ({SEGMENT_COLUMNS}, length_m) FROM STDIN") as copy:
            for i, a in enumerate(chunk.attributes):
                doc = attrs_json.get(id(a))
                if doc is None:
                    doc = attrs_json[id(a)] = json.dumps(a.attrs)
                copy.write_row((self.network_id, src[i], dst[i], geoms[i], a.lanes_forward,
                                a.lanes_backward, a.speed_limit_kph, a.oneway, a.road_class,
                                a.is_junction, a.name, a.surface, a.width_m, a.external_id,
                                doc, a.confidence, 0))

    def nodes(self, coords: np.ndarray, degree: np.ndarray,
              extras: list[NodePoint | None]) -> None:
        geoms = _ewkb(coords)
        with self.conn.cursor() as cur, cur.copy(
                "COPY road_nodes (id, network_id, geom, kind, traffic_light, external_id) "
                "FROM STDIN") as copy:
            for node_id, geom, d, p in zip(self.node_ids.tolist(), geoms, degree.tolist(),
                                           extras, strict=True):
                copy.write_row((node_id, self.network_id, geom, node_kind(d),
                                bool(p and p.traffic_light), p.external_id if p else None))

    def publish(self) -> None:
        with self.conn.cursor() as cur:
            cur.execute(insert_segments({c: c for c in SEGMENT_COLUMNS.split(", ")},
                                        "staging_segments"))
            cur.execute("DROP TABLE staging_segments")


def store_lines(session: Session, network: str, read: Read, *, replace: bool = False,
                allow_empty: bool = True, crossings_noded: int = 0,
                progress: Progress | None = None) -> ImportSummary:
    """Node the lines ``read()`` yields and store them as network ``network`` (two passes).

    The caller owns the transaction. Raises :class:`NoLinesError` when there is no line and
    ``allow_empty`` is false (nothing is written then).
    """
    report = progress or (lambda message, fraction: None)
    noder = Noder()
    for lines, points in _chunked(read()):
        noder.add_points(points)
        noder.scan(lines)
        report(f"read {noder.lines_scanned:,} lines", 0.0)
    if not noder.lines_scanned and not allow_empty:
        raise NoLinesError("no road lines found")
    noder.freeze()
    report(f"read {noder.lines_scanned:,} lines", READ_SHARE)
    session.execute(text("SELECT set_config('ugvmap.bulk_load', 'on', true)"))
    network_id = _network_id(session, network, replace)
    stager = _Stager(session, network_id)
    done = segments = 0
    for lines, _ in _chunked(read()):
        chunk = noder.split(lines)
        stager.reserve(noder.node_count)
        stager.segments(chunk)
        done, segments = done + len(lines), segments + len(chunk)
        report(f"noded {done:,} of {noder.lines_scanned:,} lines",
               READ_SHARE + SPLIT_SHARE * done / max(1, noder.lines_scanned))
    stager.nodes(*noder.nodes())
    report(f"storing {segments:,} segments", READ_SHARE + SPLIT_SHARE)
    stager.publish()
    session.execute(text("SELECT set_config('ugvmap.bulk_load', 'off', true)"))
    session.execute(text("SELECT ugvmap_overview_refresh(:id, NULL), "
                         "ugvmap_network_bump(:id, NULL)"), {"id": network_id})
    total: float = session.execute(text("SELECT COALESCE(sum(length_m), 0) FROM road_segments "
                                 "WHERE network_id = :id"), {"id": network_id}).scalar_one()
    report(f"stored {segments:,} segments", 1.0)
    return ImportSummary(network=network, network_id=network_id, segments=segments,
                         nodes=noder.node_count, total_length_m=float(total),
                         lines_read=noder.lines_scanned,
                         duplicates_dropped=noder.duplicates_dropped,
                         crossings_noded=crossings_noded)


def write_network(session: Session, network: str, lines: Iterable[FeatureLike], *,
                  replace: bool = False, node_crossings: bool = True,
                  node_points: Iterable[NodePoint] = (),
                  progress: Progress | None = None) -> ImportSummary:
    """Node ``lines`` (held in memory) into a topology and store it as network ``network``.

    ``node_crossings=False`` trusts the input's own topology (OSM shared nodes, our exports):
    lines then connect only where they share a vertex. The caller owns the transaction.
    """
    road_lines = [part for feature in lines for part in as_road_lines(feature)]
    crossed = 0
    if node_crossings and road_lines:
        road_lines, crossed = noding.node_crossings(road_lines)
    points = list(node_points)
    return store_lines(session, network, lambda: itertools.chain(points, road_lines),
                       replace=replace, crossings_noded=crossed, progress=progress)
