"""Topology clean-up (gap bridging, crumbs) and the APLS connectivity score, on known graphs.

Every grid is 1 m per pixel, so pixel counts are metres.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ingest.roads.connectivity import apls, connectivity_report, graph_from_lines
from ingest.roads.skeleton import neighbour_count
from ingest.roads.topology import (
    TopologyParams,
    bridge_gaps,
    clean_topology,
    drop_short_fragments,
)


def components(skel: np.ndarray) -> int:
    return cv2.connectedComponents(skel.astype(np.uint8), connectivity=8)[0] - 1


def broken_road(gap: tuple[int, int] = (140, 152), support: float = 0.5
                ) -> tuple[np.ndarray, np.ndarray]:
    """A straight road along row 100 with a gap (12 m by default); ``support`` along the gap."""
    skel = np.zeros((200, 300), bool)
    skel[100, 20:gap[0]] = True
    skel[100, gap[1]:280] = True
    prob = np.zeros(skel.shape, np.float32)
    prob[98:103, 20:280] = support
    prob[skel] = 0.9
    return skel, prob


def test_a_gap_the_probability_supports_is_bridged_once() -> None:
    skel, prob = broken_road()
    assert components(skel) == 2
    out = bridge_gaps(skel, prob, 1.0)
    assert components(out) == 1
    assert out[100, 140:152].all()
    # The two facing dead ends share one straight bridge: nothing else was drawn.
    assert out.sum() == 260
    assert neighbour_count(out)[out].max() == 2


def test_a_gap_with_no_road_probability_stays_open() -> None:
    skel, prob = broken_road(support=0.0)
    assert np.array_equal(bridge_gaps(skel, prob, 1.0), skel)


def test_a_gap_longer_than_the_limit_stays_open_and_zero_switches_bridging_off() -> None:
    skel, prob = broken_road(gap=(100, 160))
    assert components(bridge_gaps(skel, prob, 1.0)) == 2
    assert components(bridge_gaps(skel, prob, 1.0, TopologyParams(bridge_max_m=70))) == 1
    short, short_prob = broken_road()
    off = TopologyParams(bridge_max_m=0.0)
    assert np.array_equal(bridge_gaps(short, short_prob, 1.0, off), short)


def test_dead_ends_side_by_side_are_not_bridged() -> None:
    """Two dead ends 12 m apart at 90 degrees to where both point: no road continues there."""
    skel = np.zeros((200, 300), bool)
    skel[100, 20:140] = True            # ends at column 139, pointing east
    skel[112, 20:140] = True            # parallel, ends right below it, also pointing east
    prob = np.full(skel.shape, 0.9, np.float32)
    assert np.array_equal(bridge_gaps(skel, prob, 1.0), skel)


def test_a_side_road_pointing_at_a_through_road_is_joined_to_it() -> None:
    skel = np.zeros((200, 300), bool)
    skel[100, 20:280] = True            # a through road
    skel[30:88, 150] = True             # a side road ending 12 m short of it, pointing at it
    skel[20, 60:140] = True             # a road ending 10 m beside the side road's far end
    prob = np.full(skel.shape, 0.5, np.float32)
    out = bridge_gaps(skel, prob, 1.0)
    assert out[88:100, 150].all()       # the T is closed, straight down
    assert not out[20, 140:150].any()   # the perpendicular neighbour is left alone
    assert components(out) == 2


def test_a_dead_end_curling_back_onto_its_own_road_is_not_bridged() -> None:
    """A hairpin whose end points at its own road 6 m away, 38 m back along the skeleton:
    bridging it would make a tiny loop, not close a gap."""
    skel = np.zeros((200, 300), bool)
    skel[100, 20:131] = True
    skel[100:113, 130] = True
    skel[112, 120:131] = True
    skel[106:113, 120] = True           # ends at row 106 pointing north at row 100
    prob = np.full(skel.shape, 0.9, np.float32)
    assert np.array_equal(bridge_gaps(skel, prob, 1.0), skel)


@pytest.mark.parametrize("offset", [3, 10])
def test_facing_dead_ends_offset_sideways_get_one_bridge(offset: int) -> None:
    """At 10 m each end's best target is the other road's second pixel, not its end: without
    retiring the other dead end, two crossing bridges would make an X of fake junctions."""
    skel = np.zeros((200, 300), bool)
    skel[100, 20:140] = True
    skel[100 + offset, 152:280] = True
    prob = np.full(skel.shape, 0.5, np.float32)
    out = bridge_gaps(skel, prob, 1.0)
    assert components(out) == 1
    assert neighbour_count(out)[out].max() == 2       # one line: no loop, no junction
    assert out.sum() - skel.sum() <= 13


def test_a_dead_end_pointing_at_its_own_road_far_along_it_is_bridged() -> None:
    """The same shape as a 250 m block whose last corner the threshold broke: a real loop."""
    skel = np.zeros((200, 300), bool)
    skel[50, 50:201] = True
    skel[50:151, 200] = True
    skel[150, 50:201] = True
    skel[62:151, 50] = True             # ends 12 m below the first corner, pointing at it
    prob = np.full(skel.shape, 0.6, np.float32)
    out = bridge_gaps(skel, prob, 1.0)
    assert out[51:62, 50].all()                   # (thinning may cut the corner pixel)
    assert neighbour_count(out)[out].min() == 2   # a closed ring: no dead end left


def test_short_isolated_fragments_go_long_roads_stay() -> None:
    skel = np.zeros((200, 300), bool)
    skel[50, 20:120] = True             # 100 m road
    skel[150, 20:30] = True             # 10 m crumb
    out = drop_short_fragments(skel, 1.0, 40.0)
    assert out[50, 20:120].all()
    assert not out[150].any()


def test_fragment_length_counts_diagonals_at_their_length() -> None:
    """32 diagonal pixels are a 45 m road: counting pixels would call it 32 m and drop it."""
    skel = np.zeros((100, 100), bool)
    idx = np.arange(10, 42)
    skel[idx, idx] = True
    assert drop_short_fragments(skel, 1.0, 40.0).sum() == 32
    assert drop_short_fragments(skel, 1.0, 50.0).sum() == 0
    assert drop_short_fragments(skel, 0.5, 40.0).sum() == 0     # 22.4 m at 0.5 m/px


def test_clean_topology_keeps_a_crumb_that_bridging_connects() -> None:
    skel, prob = broken_road(gap=(140, 152))
    skel[100, 170:280] = False          # the far piece is now an 18 m crumb...
    prob[98:103, 170:280] = 0
    skel[150, 20:30] = True             # ...and this 10 m one connects to nothing
    out = clean_topology(skel, prob, 1.0)
    assert out[100, 20:170].all()
    assert not out[150].any()
    assert components(out) == 1


def grid_lines(n: int = 5, step: float = 100.0, cut: bool = False) -> list[np.ndarray]:
    """An n x n street grid, each street one polyline with a vertex at every crossing; with
    ``cut`` the street x = 2 step is broken between y = 1.4 step and 1.6 step."""
    ticks = np.arange(n) * step
    lines = []
    for t in ticks:
        lines.append(np.column_stack([np.full(n, t), ticks]))      # x = t
        lines.append(np.column_stack([ticks, np.full(n, t)]))      # y = t
    if cut:
        street = lines.pop(4)
        lines.append(np.vstack([street[:2], [[2 * step, 1.4 * step]]]))
        lines.append(np.vstack([[[2 * step, 1.6 * step]], street[2:]]))
    return lines


def test_graph_from_lines_nodes_ends_and_shared_vertices_only() -> None:
    g = graph_from_lines(grid_lines(n=3))
    assert g.number_of_nodes() == 9 and g.number_of_edges() == 12
    assert sorted(d for _, d in g.degree()) == [2, 2, 2, 2, 3, 3, 3, 3, 4]
    assert all(w == pytest.approx(100.0) for *_, w in g.edges(data="weight"))
    overpass = graph_from_lines([np.array([[0, 50], [100, 50]]), np.array([[50, 0], [50, 100]])])
    assert overpass.number_of_nodes() == 4 and overpass.number_of_edges() == 2
    ring = graph_from_lines([np.array([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]])])
    assert sum(w for *_, w in ring.edges(data="weight")) == pytest.approx(40.0)


def test_apls_of_a_graph_against_itself_is_one() -> None:
    report = connectivity_report(grid_lines(), grid_lines(), snap_radius=5)
    assert report == {"apls": 1.0, "gt_to_pred": 1.0, "pred_to_gt": 1.0,
                      "pairs_preserved": 1.0}


def test_apls_drops_when_a_street_is_cut() -> None:
    report = connectivity_report(grid_lines(), grid_lines(cut=True), snap_radius=5)
    assert 0.5 < report["apls"] < 0.99
    assert report["gt_to_pred"] < 0.99 and report["pred_to_gt"] < 0.99
    assert 0.5 < report["pairs_preserved"] < 1.0


def test_apls_sampling_fewer_pairs_is_seeded() -> None:
    def sampled(seed: int) -> float:
        return apls(grid_lines(), grid_lines(cut=True), snap_radius=5, n_pairs=60, seed=seed)

    assert sampled(1) == sampled(1)
    assert 0.5 < sampled(1) < 1.0
    assert apls(grid_lines(), grid_lines(), snap_radius=5, n_pairs=60) == 1.0


def test_apls_tolerates_a_shift_within_the_snap_radius_only() -> None:
    shifted = [line + 3.0 for line in grid_lines()]
    assert apls(grid_lines(), shifted, snap_radius=5) > 0.99
    assert apls(grid_lines(), [line + 20.0 for line in grid_lines()], snap_radius=5) == 0.0


def test_apls_matches_a_node_on_the_middle_of_a_predicted_edge() -> None:
    """Truth has a vertex node half-way; the prediction is one straight line through it."""
    truth = [np.array([[0.0, 0.0], [50.0, 0.0]]), np.array([[50.0, 0.0], [100.0, 0.0]])]
    report = connectivity_report(truth, [np.array([[0.0, 1.0], [100.0, 1.0]])], snap_radius=5)
    assert report["gt_to_pred"] == pytest.approx(1.0)


def test_apls_of_empty_inputs_is_zero() -> None:
    assert apls(grid_lines(), [], snap_radius=5) == 0.0
    assert apls([], grid_lines(), snap_radius=5) == 0.0
    assert apls([], [], snap_radius=5) == 0.0
    assert connectivity_report([], [], 5.0)["pairs_preserved"] == 0.0


def test_apls_snaps_onto_edges_of_different_vertex_counts() -> None:
    """Regression: edges with different vertex counts crashed the edge snapping (a ragged
    array handed to shapely.linestrings)."""
    truth = [np.array([[0, 0], [50, 0]]), np.array([[50, 0], [100, 0]]),
             np.array([[50, 0], [50, 50]])]
    # The T's junction has no predicted node within 5 m: it snaps onto the 3-vertex edge.
    pred = [np.array([[0, 1], [30, 1], [100, 1]]), np.array([[50, 8], [50, 50]])]
    report = connectivity_report(truth, pred, snap_radius=5)
    assert 0.0 < report["apls"] < 1.0
