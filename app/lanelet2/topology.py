"""Road-level decisions of the Lanelet2 export: lanes per direction, lane widths, what is
degenerate and what is done with it, and what each node becomes.

Every segment end is an *arm* of its node (arm ``2 s`` is segment ``s``'s start, ``2 s + 1`` its
end), with the lanes that enter the node along it and the lanes that leave. A node becomes:

- a **dead end** (one arm): the lanelets just end;
- a **joint** (two arms whose cross-sections continue: as many lanes in as the other has out,
  and the other way round, same lane width): the lanelets of both segments share their end
  points (mitred), so lanelet2 sees them as successors with no connecting lanelet;
- an **opening** (two arms of one painted segment cut where its lane count changes: a lane
  that opens or ends, :mod:`app.lanelet2.paint`): the lanes that carry on share their end
  points as at a joint, and the lane that opens starts from a point (both its bounds begin
  where the narrower road's bound beside it ends) and widens, or narrows to one where it ends:
  lanelet2 sees one lanelet follow the other and the new lane beside it, reached by a lane
  change where the line between them allows one, as it is driven;
- a **junction** (three or more arms, or two that do not continue): every arm is cut back from
  the node by the junction radius (half the widest road meeting there + 1 m, or more where
  roads meet at an acute angle, until they no longer overlap; at most 40 % of the segment),
  and connecting lanelets join each incoming lane to the outgoing lanes of every *other* arm.
  A joint whose shared points would fold a bound is made a junction too. There is no
  movement from an arm into its own opposite lanes (no U-turn lanelets), as in Autoware's
  maps.

Degenerate segments are reported (:class:`Defect`, with the segment id) and handled by one
rule each, so the rest of the map is still written and valid:

- **zero length** (shorter than 1 cm): not mapped; its two end nodes become one node, so the
  roads at either end still connect (ugvmap's router crosses it at no cost);
- **self-loop** (starts and ends at one node): mapped like any road whose two ends are two
  arms of that node (ugvmap's router never drives a loop; the map can);
- **no lanes** in a direction it may be driven (``lanes_forward = 0`` on a two-way road, or in
  a one-way road's own direction): one lane is mapped there, as the router drives it; lanes
  against a one-way direction are ignored (one-way wins, as in routing);
- **duplicate** (same two end nodes and a line within 0.5 m of another's): only the lower id
  is mapped; **overlap** (lines sharing a stretch otherwise): reported, both mapped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from app.lanelet2.roads import RoadTable

MAX_LANES = 8
MIN_LENGTH_M = 0.01
DUPLICATE_TOLERANCE_M = 0.5
JUNCTION_MARGIN_M = 1.0
MAX_CUT_SHARE = 0.4
MAX_APART_CUT_M = 30.0
LANE_WIDTH_LIMITS_M = (1.0, 6.0)
DEFAULT_LANE_WIDTH_M = 3.0
LANE_WIDTH_M: dict[str, float] = {
    "motorway": 3.75, "motorway_link": 3.5, "trunk": 3.5, "trunk_link": 3.5,
    "primary": 3.5, "primary_link": 3.25, "secondary": 3.25, "secondary_link": 3.25,
    "tertiary": 3.0, "tertiary_link": 3.0, "unclassified": 3.0, "residential": 3.0,
    "road": 3.0, "living_street": 2.75, "service": 2.75, "track": 2.5,
    "path": 1.5, "footway": 1.5, "cycleway": 1.5, "bridleway": 1.5, "pedestrian": 2.5,
    "steps": 1.5, "corridor": 1.5,
}
"""Lane width by road class where a segment has no ``width_m`` (metres, per lane)."""

DEAD_END, JOINT, JUNCTION, OPENING = 1, 2, 3, 4


@dataclass(frozen=True)
class Defect:
    """A degenerate segment and what the export did with it."""

    segment_id: int
    kind: str
    rule: str

    def __str__(self) -> str:
        return f"segment {self.segment_id}: {self.kind}: {self.rule}"


def effective_lanes(roads: RoadTable) -> tuple[np.ndarray, np.ndarray, list[Defect]]:
    """Lanes mapped per direction: the stored counts (at most 8) where the road may be driven,
    one where it may be driven but says 0 (reported), none against a one-way direction."""
    forward_ok = roads.oneway != "backward"
    backward_ok = roads.oneway != "forward"
    fwd = np.where(forward_ok, np.clip(roads.lanes_forward, 0, MAX_LANES), 0)
    bwd = np.where(backward_ok, np.clip(roads.lanes_backward, 0, MAX_LANES), 0)
    defects = []
    for i in np.flatnonzero((forward_ok & (fwd == 0)) | (backward_ok & (bwd == 0))):
        side = "forward" if forward_ok[i] and fwd[i] == 0 else "backward"
        defects.append(Defect(int(roads.ids[i]), "no-lanes",
                              f"lanes_{side} is 0 on a direction it may be driven "
                              f"(oneway={roads.oneway[i]}): 1 lane mapped"))
    return (np.where(forward_ok, np.maximum(fwd, 1), 0),
            np.where(backward_ok, np.maximum(bwd, 1), 0), defects)


def lanes_fit(oneway: str, forward: int, backward: int) -> bool:
    """Whether lanes read from the paint are the ones the map draws for the road as they
    are (:func:`effective_lanes` changes none of them): at least one lane each way it may be
    driven, none against its one-way direction, at most :data:`MAX_LANES` each way."""
    return (forward <= MAX_LANES and backward <= MAX_LANES
            and (forward >= 1) == (oneway != "backward")
            and (backward >= 1) == (oneway != "forward"))


def lane_widths(roads: RoadTable, lanes: np.ndarray) -> np.ndarray:
    """Per segment, the width of one lane: ``width_m`` shared by its mapped lanes, else the
    class default (:data:`LANE_WIDTH_M`), within 1..6 m."""
    default = np.array([LANE_WIDTH_M.get(c, DEFAULT_LANE_WIDTH_M) for c in roads.road_class],
                       dtype=np.float64)
    given = roads.width_m / np.maximum(lanes, 1)
    width = np.where(np.isfinite(given) & (given > 0), given, default)
    return np.clip(width, *LANE_WIDTH_LIMITS_M)


def contract_zero_length(roads: RoadTable, length: np.ndarray, source: np.ndarray,
                         target: np.ndarray, n_nodes: int
                         ) -> tuple[np.ndarray, np.ndarray, list[Defect]]:
    """(segments kept, node index -> the node it merges into, defects): segments shorter
    than :data:`MIN_LENGTH_M` are dropped and their end nodes merged (lowest index wins)."""
    short = length < MIN_LENGTH_M
    defects = [Defect(int(roads.ids[i]), "zero-length",
                      f"{length[i]:.3f} m long: not mapped, its end nodes joined into one")
               for i in np.flatnonzero(short)]
    rep = np.arange(n_nodes)
    if short.any():
        graph = coo_matrix((np.ones(int(short.sum())), (source[short], target[short])),
                           shape=(n_nodes, n_nodes))
        _, label = connected_components(graph, directed=False)
        lowest = np.full(label.max() + 1, n_nodes)
        np.minimum.at(lowest, label, np.arange(n_nodes))
        rep = lowest[label]
    return ~short, rep, defects


def loops(roads: RoadTable, source: np.ndarray, target: np.ndarray,
          keep: np.ndarray) -> list[Defect]:
    """Self-loops among the kept segments (reported; mapped like any road)."""
    return [Defect(int(roads.ids[i]), "self-loop",
                   "starts and ends at one node: mapped as a road whose two ends meet at it "
                   "(ugvmap's router does not drive loops)")
            for i in np.flatnonzero(keep & (source == target))]


def duplicates(ids: np.ndarray, lines: np.ndarray, source: np.ndarray, target: np.ndarray
               ) -> tuple[np.ndarray, list[Defect]]:
    """(segments to drop, defects) among ``lines`` (shapely, metric): a segment with the same
    end nodes as a lower id and a line within :data:`DUPLICATE_TOLERANCE_M` of it is dropped;
    lines sharing a stretch otherwise are reported and kept."""
    tree = shapely.STRtree(lines)
    pairs = np.concatenate([tree.query(lines, predicate="overlaps"),
                            tree.query(lines, predicate="covers")], axis=1)
    a, b = np.minimum(pairs[0], pairs[1]), np.maximum(pairs[0], pairs[1])
    uniq = np.unique(np.column_stack([a, b])[a != b], axis=0)
    drop = np.zeros(len(lines), bool)
    defects = []
    for i, j in uniq.tolist():
        same_ends = {source[i], target[i]} == {source[j], target[j]}
        if same_ends and shapely.hausdorff_distance(lines[i], lines[j]) <= DUPLICATE_TOLERANCE_M:
            drop[j] = True
            defects.append(Defect(int(ids[j]), "duplicate",
                                  f"same ends and line as segment {ids[i]}: not mapped"))
        else:
            shared = shapely.length(shapely.intersection(lines[i], lines[j]))
            defects.append(Defect(int(ids[j]), "overlap",
                                  f"shares {shared:.1f} m with segment {ids[i]}: both mapped"))
    return drop, defects


@dataclass
class Arms:
    """Every segment end as an arm of its node, and what each node becomes."""

    node: np.ndarray  # (2S) node index of each arm
    lanes_in: np.ndarray  # (2S) lanes entering the node along the arm
    lanes_out: np.ndarray  # (2S) lanes leaving it
    kind: np.ndarray  # (N) DEAD_END / JOINT / JUNCTION, 0 for nodes without arms
    partner: np.ndarray  # (2S) the other arm of a joint, -1 elsewhere
    cut_m: np.ndarray  # (2S) how far the lanelets stop short of the node
    order: np.ndarray  # arms sorted by node (stable: by arm index within a node)
    starts: np.ndarray  # (N + 1) where each node's arms start in ``order``


def arms(source: np.ndarray, target: np.ndarray, forward: np.ndarray, backward: np.ndarray,
         width: np.ndarray, length: np.ndarray, away: np.ndarray, n_nodes: int,
         no_joint: np.ndarray | None = None, opening: np.ndarray | None = None) -> Arms:
    """Classify the nodes and place the junction cuts (rules in the module docstring);
    nodes flagged in ``no_joint`` become junctions even where the lanes continue (the
    export's geometry check asks for it where a joint's shared points would fold a bound);
    two-arm nodes flagged in ``opening`` (where a painted segment's lane count changes) are
    openings where their lanes do not continue."""
    node = np.column_stack([source, target]).ravel()
    lanes_in = np.column_stack([backward, forward]).ravel()
    lanes_out = np.column_stack([forward, backward]).ravel()
    arm_width = np.repeat(width, 2)
    order = np.argsort(node, kind="stable")
    count = np.bincount(node, minlength=n_nodes)
    starts = np.concatenate([[0], np.cumsum(count)])
    kind = np.where(count == 1, DEAD_END, np.where(count >= 2, JUNCTION, 0))
    partner = np.full(len(node), -1, np.int64)
    two = np.flatnonzero(count == 2)
    a, b = order[starts[two]], order[starts[two] + 1]
    continues = ((lanes_in[a] == lanes_out[b]) & (lanes_out[a] == lanes_in[b])
                 & (np.abs(arm_width[a] - arm_width[b]) < 0.01))
    opens = np.zeros(len(two), bool) if opening is None else opening[two] & ~continues
    if no_joint is not None:
        continues &= ~no_joint[two]
        opens &= ~no_joint[two]
    kind[two[continues]] = JOINT
    kind[two[opens]] = OPENING
    paired = continues | opens
    partner[a[paired]], partner[b[paired]] = b[paired], a[paired]
    half = (lanes_in + lanes_out) * arm_width / 2.0
    radius = np.zeros(n_nodes)
    np.maximum.at(radius, node, half)
    cap = MAX_CUT_SHARE * np.repeat(length, 2)
    cut = np.maximum(radius[node] + JUNCTION_MARGIN_M, _apart(node, order, count, away, half,
                                                               cap))
    cut = np.minimum(np.where(kind[node] == JUNCTION, cut, 0.0), cap)
    return Arms(node, lanes_in, lanes_out, kind, partner, cut, order, starts)


def _apart(node: np.ndarray, order: np.ndarray, count: np.ndarray, away: np.ndarray,
           half: np.ndarray, cap: np.ndarray) -> np.ndarray:
    """Per arm, how far from the node it must end for its road to clear every other road
    meeting there. Two roads leaving at an angle θ are ``2 d sin(θ/2)`` apart at distance d
    along each, which must reach the sum of their half widths: together they must end
    ``(h_a + h_b) / sin(θ/2)`` from the node, shared equally, or as much as a short arm (its
    ``cap``) cannot take by the other one. Without it, roads meeting at an acute angle (a
    roundabout's entry, a slip road) overlap where their lanes end and no lanelet can join
    them."""
    need = np.zeros(len(node))
    by_node = node[order]
    for shift in range(1, int(count.max(initial=1))):
        same = by_node[:-shift] == by_node[shift:]
        a, b = order[:-shift][same], order[shift:][same]
        cos = np.clip(np.einsum("ij,ij->i", away[a], away[b]), -1.0, 1.0)
        sin_half = np.sqrt((1.0 - cos) / 2.0)
        total = np.minimum((half[a] + half[b]) / np.maximum(sin_half, 1e-9),
                           2 * MAX_APART_CUT_M)
        da = np.minimum(np.maximum(total / 2, total - cap[b]), MAX_APART_CUT_M)
        db = np.minimum(np.maximum(total / 2, total - cap[a]), MAX_APART_CUT_M)
        np.maximum.at(need, a, da)
        np.maximum.at(need, b, db)
    return need
