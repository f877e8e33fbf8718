"""Topology invariants of a stored network, checked by ``ugvmap network validate``.

Errors break the contract the planner relies on (a segment that does not end at its node,
a node whose kind lies about its degree, a duplicate segment). Findings that are legitimate
in real data (dead ends, several components, e.g. islands cut by an extract boundary) are
reported as statistics, not errors.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import networkx as nx
from sqlalchemy import text
from sqlalchemy.orm import Session

from app.errors import UserError

SAMPLE = 10

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
    "node kind does not match its degree": """
        SELECT id FROM (SELECT n.id, n.kind, (SELECT count(*) FROM road_segments s
                    WHERE s.source_node = n.id) + (SELECT count(*) FROM road_segments s
                    WHERE s.target_node = n.id) AS degree
                  FROM road_nodes n WHERE n.network_id = :n) d
         WHERE kind <> CASE WHEN degree >= 3 THEN 'junction'
                            WHEN degree = 1 THEN 'endpoint' ELSE 'node' END""",
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


@dataclass
class IntegrityReport:
    """What ``ugvmap network validate`` found: counts, and the ids breaking each invariant."""
    network: str
    segments: int = 0
    nodes: int = 0
    dead_ends: int = 0
    components: int = 0
    largest_component_share: float = 0.0
    errors: dict[str, list[int]] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """True when no invariant is broken (dead ends and components are facts, not errors)."""
        return not self.errors

    def lines(self) -> list[str]:
        """The report as printed lines, at most a few ids per problem so a broken import stays
        readable."""
        out = [f"network {self.network}: {self.segments} segments, {self.nodes} nodes, "
               f"{self.dead_ends} dead ends, {self.components} connected components "
               f"(largest holds {self.largest_component_share:.1%} of segments)"]
        for problem, ids in self.errors.items():
            shown = ", ".join(map(str, ids[:SAMPLE]))
            more = f" and {len(ids) - SAMPLE} more" if len(ids) > SAMPLE else ""
            out.append(f"ERROR {problem}: {len(ids)} (ids {shown}{more})")
        out.append("topology OK" if self.ok else f"{len(self.errors)} kinds of error")
        return out


def check_network(session: Session, network: str) -> IntegrityReport:
    """Run every topology check on the network in SQL (the data may be too big for Python)."""
    network_id = session.execute(text("SELECT id FROM networks WHERE name = :n"),
                                 {"n": network}).scalar()
    if network_id is None:
        raise UserError(f"network {network[:100]!r} does not exist")
    report = IntegrityReport(network)
    for problem, sql in CHECKS.items():
        ids = [r[0] for r in session.execute(text(sql), {"n": network_id})]
        if ids:
            report.errors[problem] = sorted(ids)
    edges = session.execute(text("SELECT source_node, target_node FROM road_segments "
                                 "WHERE network_id = :n"), {"n": network_id}).all()
    graph = nx.MultiGraph()
    graph.add_edges_from(edges)
    report.segments = len(edges)
    report.nodes = session.execute(text("SELECT count(*) FROM road_nodes WHERE network_id = :n"),
                                   {"n": network_id}).scalar_one()
    report.dead_ends = sum(1 for _, d in graph.degree() if d == 1)
    components = list(nx.connected_components(graph))
    report.components = len(components)
    if edges:
        largest = max(components, key=len)
        report.largest_component_share = sum(1 for a, _ in edges if a in largest) / len(edges)
    return report
