"""Planner attributes of an extracted road graph, from what the image shows.

Every rule reads only the graph (widths, lengths, how segments connect) and the rule table
(:class:`~app.network.settings.AttributeRules`, defaults documented there and in the README,
overridable per job or per network), so the same picture always gives the same attributes:

- **Lanes**: total = round(width / lane width), 1..8. Nothing in an aerial or IPM image says
  a road is one-way, so extracted roads are two-way and their lanes are split *evenly*:
  total // 2 per direction (at least 1). An odd total of 3 or more means a centre lane both
  directions share (a turn or overtaking lane: OSM's ``lanes:both_ways=1``, kept in ``attrs``);
  it is never handed to one direction, since the image cannot say which.
- **Through** (position in the hierarchy): the segment's edge betweenness (share of
  length-weighted shortest paths between node pairs that use it, networkx) relative to the
  busiest segment: 1 on the network's main through-route, near 0 on cul-de-sacs and spurs.
- **Class**: the first row of the class table whose minimum width and minimum through the
  segment meets (defaults: secondary ≥ 10 m wide and ≥ 0.5 through, tertiary ≥ 6.5 m and
  ≥ 0.2, residential ≥ 4.5 m, service otherwise); no row met: ``unclassified``.
- **Speed**: the class's speed from the speed table (no entry: no speed limit).
- **is_junction** (the schema's "part of a junction, e.g. a roundabout"): a segment between
  two junction nodes (degree ≥ 3) no longer than ``junction_length_m`` (a connector inside one
  wide or staggered crossing), or a segment around a small round face of the network (a
  roundabout: perimeter ≤ 160 m, isoperimetric quotient 4πA/P² ≥ 0.85; a square block has
  0.79). Junction *nodes* are the writer's business (kind ``junction`` by degree).

Each segment's confidence is the pipeline's (the graph's ``Edge.confidence``), stored as is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import networkx as nx
import numpy as np
import shapely

from app.network.settings import AttributeRules
from ingest.roads.graph import RoadGraph

MAX_LANES = 8
ROUNDABOUT_MAX_PERIMETER_M = 160.0
ROUNDABOUT_MIN_QUOTIENT = 0.85
BETWEENNESS_SAMPLES = 300
"""Above this many nodes, betweenness is estimated from this many sources (seeded: the same
graph always gets the same classes); exact below."""


@dataclass(frozen=True)
class SegmentAttributes:
    """What the rules give one edge of the graph."""

    lanes_forward: int
    lanes_backward: int
    lanes_both_ways: int
    """Centre lane shared by both directions (0 or 1)."""
    road_class: str
    speed_limit_kph: float | None
    is_junction: bool
    through: float


def lanes(width_m: float, lane_width_m: float) -> tuple[int, int, int]:
    """(forward, backward, both ways) lanes of a two-way road ``width_m`` wide."""
    total = min(max(round(width_m / lane_width_m), 1), MAX_LANES)
    per_direction = max(total // 2, 1)
    return per_direction, per_direction, total % 2 if total >= 3 else 0


def _multigraph(graph: RoadGraph, resolution_m: float) -> nx.MultiGraph:
    g = nx.MultiGraph()
    g.add_nodes_from(n.id for n in graph.nodes)
    for i, e in enumerate(graph.edges):
        g.add_edge(e.source, e.target, key=i, length=max(e.length_m, resolution_m))
    return g


def through_shares(graph: RoadGraph, resolution_m: float) -> list[float]:
    """Each edge's betweenness relative to the largest (0..1; all 0 without through paths)."""
    g = _multigraph(graph, resolution_m)
    k = BETWEENNESS_SAMPLES if g.number_of_nodes() > BETWEENNESS_SAMPLES else None
    centrality = nx.edge_betweenness_centrality(g, k=k, weight="length", seed=0)
    by_key = {key: value for (_, _, key), value in centrality.items()}
    values = np.array([by_key.get(i, 0.0) for i in range(len(graph.edges))])
    top = values.max(initial=0.0)
    return (values / top).tolist() if top > 0 else [0.0] * len(values)


def road_class(width_m: float, through: float, rules: AttributeRules) -> str:
    """The first class-table row the segment meets, else ``unclassified``."""
    for row in rules.classes:
        if width_m >= row.min_width_m and through >= row.min_through:
            return row.road_class
    return "unclassified"


def _roundabout_edges(lines: list[shapely.LineString]) -> set[int]:
    """Edges around small, round faces of the network (lines in metres)."""
    faces = [f for f in shapely.get_parts(shapely.polygonize(lines))
             if 0 < f.length <= ROUNDABOUT_MAX_PERIMETER_M
             and 4 * math.pi * f.area / f.length ** 2 >= ROUNDABOUT_MIN_QUOTIENT]
    if not faces:
        return set()
    rims = shapely.buffer(shapely.boundary(np.array(faces, dtype=object)), 1e-6)
    return {i for i, line in enumerate(lines)
            if any(shapely.covers(rims, line))}


def junction_edges(graph: RoadGraph, resolution_m: float, rules: AttributeRules) -> set[int]:
    """Indices of the edges that are part of a junction (see the module docstring)."""
    degree = {n.id: n.degree for n in graph.nodes}
    inside = {i for i, e in enumerate(graph.edges)
              if e.source != e.target and degree[e.source] >= 3 and degree[e.target] >= 3
              and e.length_m <= rules.junction_length_m}
    lines = [shapely.LineString(e.coords * resolution_m) for e in graph.edges]
    return inside | _roundabout_edges(lines)


def segment_attributes(graph: RoadGraph, resolution_m: float,
                       rules: AttributeRules) -> list[SegmentAttributes]:
    """The rules applied to every edge of ``graph`` (working-grid pixels of ``resolution_m``)."""
    through = through_shares(graph, resolution_m)
    junctions = junction_edges(graph, resolution_m, rules)
    out = []
    for i, e in enumerate(graph.edges):
        forward, backward, both = lanes(e.width_m, rules.lane_width_m)
        cls = road_class(e.width_m, through[i], rules)
        out.append(SegmentAttributes(forward, backward, both, cls, rules.speed(cls),
                                     i in junctions, round(through[i], 4)))
    return out
