"""The re-survey matching on small synthetic networks in metres, one outcome at a time: each
scene is built with a known answer (which roads moved, which are new or gone) and re-digitised
with noise and a different vertex spacing, as a new survey would be."""

from __future__ import annotations

from collections.abc import Collection

import numpy as np
import pytest
from shapely import LineString, box

from app.network.resurvey.frame import LocalFrame
from app.network.resurvey.matching import OldSegment, Tolerances, match


def redraw(coords: list[tuple[float, float]], seed: int, spacing: float = 3.7,
           noise: float = 0.5, shift: float = 0.0) -> np.ndarray:
    """The line digitised again: vertices every ``spacing`` m, each off by ~``noise`` m,
    the whole line offset sideways by ``shift`` m."""
    line = LineString(coords)
    if shift:
        line = line.offset_curve(shift)
    count = max(2, round(line.length / spacing) + 1)
    points = np.array([line.interpolate(d).coords[0]
                       for d in np.linspace(0, line.length, count)])
    rng = np.random.default_rng(seed)
    return points + rng.normal(0, noise, points.shape)


def segments(*lines: list[tuple[float, float]], edited: Collection[int] = ()
             ) -> list[OldSegment]:
    return [OldSegment(i + 1, np.array(c, float), i + 1 in edited) for i, c in enumerate(lines)]


STREET = [(0.0, 0.0), (100.0, 0.0)]
AVENUE = [(100.0, 0.0), (100.0, 120.0)]
LANE = [(0.0, 0.0), (-30.0, 80.0), (-10.0, 160.0)]


def test_a_noisy_redigitised_network_is_unchanged() -> None:
    old = segments(STREET, AVENUE, LANE)
    result = match(old, [redraw(STREET, 1), redraw(AVENUE, 2, 6.1), redraw(LANE, 3, 1.3)])
    assert set(result.unchanged) == {1, 2, 3}
    assert all(offset < 1.0 for offset in result.unchanged.values())
    assert not result.moved and not result.new and not result.missing


def test_a_road_moved_four_metres_is_proposed_on_its_own_nodes() -> None:
    old = segments(STREET, AVENUE)
    result = match(old, [redraw(STREET, 1), redraw(AVENUE, 2, shift=4.0)])
    assert set(result.unchanged) == {1}
    [moved] = result.moved
    assert moved.segment_id == 2 and 3.0 < moved.offset_m < 5.0
    assert moved.coords[0].tolist() == [100.0, 0.0] and moved.coords[-1].tolist() == [100, 120]
    middle = moved.coords[len(moved.coords) // 2]
    assert 3.0 < abs(middle[0] - 100.0) < 5.0  # the proposed course is the new one
    assert not result.new and not result.missing


def test_a_new_road_joins_the_side_of_the_old_one_it_starts_from() -> None:
    old = segments(STREET)
    branch = [(40.0, 0.3), (40.0, 70.0)]  # starts on the street: a new T junction there
    result = match(old, [redraw(STREET, 1), redraw(branch, 2)])
    assert set(result.unchanged) == {1}
    [road] = result.new
    assert road.joins == (1, None)
    assert abs(road.coords[0][1]) < 1e-6 and 38 < road.coords[0][0] < 42  # on the street
    assert LineString(road.coords).length == pytest.approx(70, abs=3)


def test_a_new_road_from_an_old_junction_joins_that_node() -> None:
    old = segments(STREET, AVENUE)
    spur = [(101.0, 1.0), (160.0, 40.0)]
    [road] = match(old, [redraw(STREET, 1), redraw(AVENUE, 2), redraw(spur, 3)]).new
    assert road.coords[0].tolist() == [100.0, 0.0]  # the node itself, not its neighbourhood


def test_a_road_gone_from_the_survey_is_missing_but_only_inside_the_coverage() -> None:
    far = [(500.0, 0.0), (600.0, 0.0)]
    old = segments(STREET, AVENUE, far, edited={2})
    survey = [redraw(STREET, 1)]
    result = match(old, survey, coverage=box(-50, -50, 200, 200))
    [missing] = result.missing
    assert missing.segment_id == 2 and missing.edited and missing.seen_share < 0.2
    assert result.unseen == [3]  # outside the new imagery nothing is said
    assert [m.segment_id for m in match(old, survey).missing] == [2, 3]


def test_one_new_line_over_two_old_segments_and_two_new_lines_over_one() -> None:
    first, second = [(0.0, 0.0), (60.0, 0.0)], [(60.0, 0.0), (130.0, 5.0)]
    old = segments(first, second, AVENUE)
    merged = redraw([(0.0, 0.0), (60.0, 0.0), (130.0, 5.0)], 1)  # the node at 60 m not drawn
    split = [redraw([(100.0, 0.0), (100.0, 55.0)], 2), redraw([(100.0, 55.0), (100, 120)], 3)]
    result = match(old, [merged, *split])
    assert set(result.unchanged) == {1, 2, 3}
    assert not result.new and not result.missing and not result.moved


def test_a_line_that_carries_on_past_an_old_segment_adds_only_the_rest() -> None:
    old = segments(STREET)
    longer = redraw([(0.0, 0.0), (100.0, 0.0), (180.0, 0.0)], 1)  # 80 m more road
    result = match(old, [longer])
    assert set(result.unchanged) == {1}
    [road] = result.new
    assert road.joins[0] == 1 and road.coords[0].tolist() == [100.0, 0.0]  # from the end node
    assert LineString(road.coords).length == pytest.approx(80, abs=4)


def test_a_removed_carriageway_is_not_explained_by_the_one_beside_it() -> None:
    north, south = [(0.0, 8.0), (200.0, 8.0)], [(0.0, 0.0), (200.0, 0.0)]
    result = match(segments(north, south), [redraw(south, 1)])
    assert [m.segment_id for m in result.missing] == [1] and set(result.unchanged) == {2}


def test_a_crossing_road_does_not_see_the_road_it_crosses() -> None:
    crossing = [(50.0, -60.0), (50.0, 60.0)]
    result = match(segments(STREET), [redraw(crossing, 1)])
    assert [m.segment_id for m in result.missing] == [1]
    [road] = result.new
    assert LineString(road.coords).length == pytest.approx(120, abs=3)


def test_a_continuing_road_does_not_explain_a_removed_short_one() -> None:
    stub = [(100.0, 0.0), (112.0, 0.0)]  # 12 m, collinear with the street it continues
    result = match(segments(STREET, stub), [redraw(STREET, 1, noise=0.3)])
    assert [m.segment_id for m in result.missing] == [2]


def test_tolerances_are_overridable_and_checked() -> None:
    old = segments(STREET)
    survey = [redraw(STREET, 1, shift=3.0)]
    assert [m.segment_id for m in match(old, survey).moved] == [1]
    assert set(match(old, survey, tol=Tolerances(moved_m=4.0)).unchanged) == {1}
    assert [m.segment_id for m in match(old, survey, tol=Tolerances(match_m=2.0)).missing] \
        == [1]
    with pytest.raises(ValueError, match="match_m must be a positive number"):
        Tolerances(match_m=-1)
    with pytest.raises(ValueError, match="heading_deg must be below 90"):
        Tolerances(heading_deg=90)


def test_an_empty_network_makes_everything_new() -> None:
    result = match([], [redraw(STREET, 1)])
    [road] = result.new
    assert road.joins == (None, None)
    assert result.counts() == {"unchanged": 0, "moved": 0, "new": 1, "missing": 0, "unseen": 0}


def test_the_local_frame_measures_true_metres() -> None:
    frame = LocalFrame.around([[(1.5, 42.5), (1.6, 42.6)]])
    xy = frame.metres([(1.5, 42.5), (1.6, 42.5)])
    assert np.hypot(*(xy[1] - xy[0])) == pytest.approx(8_209, rel=2e-3)  # 0.1 deg at 42.5 N
    back = frame.lonlat(xy)
    assert back[1] == pytest.approx([1.6, 42.5], abs=1e-9)
