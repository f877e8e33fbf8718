"""Topology invariants of a stored network, checked by ``ugvmap network validate``.

Errors break the contract the planner relies on (a segment that does not end at its node,
a node whose kind lies about its degree, a duplicate segment). Findings that are legitimate
in real data (dead ends, several connected pieces, e.g. islands cut by an extract boundary)
are reported with where they are, not as errors: a map team reviewing an extracted network
goes to each dead end and each small piece to decide whether it is real.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from sqlalchemy import text
from sqlalchemy.orm import Session

from app.errors import UserError
from app.network.collections import KIND_OF_DEGREE, NODE_DEGREE

SAMPLE = 10
LISTED = 20
"""Pieces and dead ends printed as text (``--json`` lists every one)."""

CHECKS: dict[str, str] = {
    "segment ends away from its nodes": """
        SELECT s.id FROM road_segments s
          JOIN road_nodes a ON a.id = s.source_node JOIN road_nodes b ON b.id = s.target_node
         WHERE s.network_id = :n AND NOT (ST_Equals(ST_StartPoint(s.geom), a.geom)
                                          AND ST_Equals(ST_EndPoint(s.geom), b.geom))""",
    "segment uses a node of another network": """
        SELECT s.id FROM road_segments s
          JOIN road_nodes a ON a.id = s.source_node JOIN road_nodes b ON b.id = s.target_node
         WHERE s.network_id = :n AND (a.network_id <> :n OR b.network_id <> :n)""",
    "duplicate segment": """
        SELECT s2.id FROM road_segments s1 JOIN road_segments s2
            ON s1.id < s2.id AND s2.network_id = :n
           AND LEAST(s1.source_node, s1.target_node) = LEAST(s2.source_node, s2.target_node)
           AND GREATEST(s1.source_node, s1.target_node)
               = GREATEST(s2.source_node, s2.target_node)
           AND ST_Equals(s1.geom, s2.geom)
         WHERE s1.network_id = :n""",
    "length_m differs from the geography length": """
        SELECT id FROM road_segments WHERE network_id = :n
           AND abs(length_m - ST_Length(geom::geography)) > 1e-6 * greatest(length_m, 1)""",
    "node kind does not match its degree": f"""
        SELECT id FROM (SELECT n.id, n.kind, {NODE_DEGREE} AS degree
                  FROM road_nodes n WHERE n.network_id = :n) d
         WHERE kind <> {KIND_OF_DEGREE}""",
    "coordinates outside lon -180..180, lat -90..90": """
        SELECT id FROM road_segments WHERE network_id = :n
           AND NOT geom @ ST_MakeEnvelope(-180, -90, 180, 90, 4326)""",
    "node without segments": """
        SELECT n.id FROM road_nodes n WHERE n.network_id = :n AND NOT EXISTS (
            SELECT 1 FROM road_segments s WHERE s.source_node = n.id OR s.target_node = n.id)""",
    "two nodes at one location": """
        SELECT b.id FROM road_nodes a JOIN road_nodes b
            ON a.id < b.id AND b.network_id = :n AND ST_Equals(a.geom, b.geom)
         WHERE a.network_id = :n""",
}


@dataclass(frozen=True)
class Piece:
    """A connected piece of the network: how big it is and where."""

    segments: int
    length_km: float
    bbox: tuple[float, float, float, float]
    """minlon, minlat, maxlon, maxlat of its segments."""


@dataclass(frozen=True)
class DeadEnd:
    """A node only one segment reaches, and where it is."""

    node: int
    lon: float
    lat: float


@dataclass
class IntegrityReport:
    """What ``ugvmap network validate`` found: counts, the connected pieces (largest first),
    the dead ends, and the ids breaking each invariant."""
    network: str
    segments: int = 0
    nodes: int = 0
    pieces: list[Piece] = field(default_factory=list)
    dead_ends: list[DeadEnd] = field(default_factory=list)
    errors: dict[str, list[int]] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when no invariant is broken (dead ends and pieces are facts, not errors)."""
        return not self.errors

    @property
    def largest_piece_share(self) -> float:
        """Share of the segments in the largest connected piece."""
        return self.pieces[0].segments / self.segments if self.pieces else 0.0

    def lines(self, listed: int = LISTED) -> list[str]:
        """The report as printed lines: at most ``listed`` pieces and dead ends and a few ids
        per problem, so a broken or country-sized network stays readable."""
        out = [f"network {self.network}: {self.segments} segments, {self.nodes} nodes, "
               f"{len(self.dead_ends)} dead ends, {len(self.pieces)} connected components "
               f"(largest holds {self.largest_piece_share:.1%} of segments)"]
        for i, piece in enumerate(self.pieces[:listed], 1):
            out.append(f"  piece {i}: {piece.segments} segments, {piece.length_km:.3f} km, "
                       "bbox " + ",".join(f"{v:.6f}" for v in piece.bbox))
        if len(self.pieces) > listed:
            out.append(f"  ... and {len(self.pieces) - listed} smaller pieces (--json lists all)")
        for end in self.dead_ends[:listed]:
            out.append(f"  dead end: node {end.node} at {end.lon:.7f},{end.lat:.7f}")
        if len(self.dead_ends) > listed:
            out.append(f"  ... and {len(self.dead_ends) - listed} more dead ends (--json lists "
                       "all)")
        for problem, ids in self.errors.items():
            shown = ", ".join(map(str, ids[:SAMPLE]))
            more = f" and {len(ids) - SAMPLE} more" if len(ids) > SAMPLE else ""
            out.append(f"ERROR {problem}: {len(ids)} (ids {shown}{more})")
        out.append("topology OK" if self.ok else f"{len(self.errors)} kinds of error")
        return out

    def as_json(self) -> dict[str, Any]:
        """Everything found, for ``--json``."""
        return {"network": self.network, "ok": self.ok, "segments": self.segments,
                "nodes": self.nodes, "components": len(self.pieces),
                "pieces": [asdict(p) for p in self.pieces],
                "dead_ends": [asdict(d) for d in self.dead_ends], "errors": self.errors}


def _pieces(rows: Sequence[Any]) -> tuple[list[Piece], np.ndarray, np.ndarray]:
    """Connected pieces of the segments ``(source, target, length_m, xmin, ymin, xmax, ymax)``
    (largest first), and the node ids with their degrees."""
    if not rows:
        return [], np.zeros(0, np.int64), np.zeros(0, np.int64)
    table = np.array(rows, dtype=float)
    ends = table[:, :2].astype(np.int64)
    ids, index = np.unique(ends, return_inverse=True)
    index = index.reshape(-1, 2)
    graph = coo_matrix((np.ones(len(index)), (index[:, 0], index[:, 1])),
                       shape=(len(ids), len(ids)))
    _, label = connected_components(graph, directed=False)
    piece = label[index[:, 0]]
    order = np.argsort(piece, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(piece[order]) != 0])
    counts = np.diff(np.r_[starts, len(order)])
    km = np.add.reduceat(table[order, 2], starts) / 1000
    low = np.minimum.reduceat(table[order, 3:5], starts)
    high = np.maximum.reduceat(table[order, 5:7], starts)
    pieces = [Piece(int(c), float(k), (float(a[0]), float(a[1]), float(b[0]), float(b[1])))
              for c, k, a, b in zip(counts, km, low, high, strict=True)]
    pieces.sort(key=lambda p: (-p.segments, -p.length_km))
    return pieces, ids, np.bincount(index.ravel(), minlength=len(ids))


def check_network(session: Session, network: str) -> IntegrityReport:
    """Run every topology check on the network in SQL (the data may be too big for Python
    objects: the pieces are found with SciPy on arrays)."""
    network_id = session.execute(text("SELECT id FROM networks WHERE name = :n"),
                                 {"n": network}).scalar()
    if network_id is None:
        raise UserError(f"network {network[:100]!r} does not exist")
    report = IntegrityReport(network)
    for problem, sql in CHECKS.items():
        ids = [r[0] for r in session.execute(text(sql), {"n": network_id})]
        if ids:
            report.errors[problem] = sorted(ids)
    rows = session.execute(text(
        "SELECT source_node, target_node, length_m, ST_XMin(geom), ST_YMin(geom), "
        "ST_XMax(geom), ST_YMax(geom) FROM road_segments WHERE network_id = :n"),
        {"n": network_id}).all()
    report.segments = len(rows)
    report.nodes = session.execute(text("SELECT count(*) FROM road_nodes WHERE network_id = :n"),
                                   {"n": network_id}).scalar_one()
    report.pieces, node_ids, degree = _pieces(rows)
    dead = node_ids[degree == 1].tolist()
    report.dead_ends = [DeadEnd(r.id, r.lon, r.lat) for r in session.execute(text(
        "SELECT id, ST_X(geom) AS lon, ST_Y(geom) AS lat FROM road_nodes "
        "WHERE id = ANY(:ids) ORDER BY id"), {"ids": dead})]
    return report
