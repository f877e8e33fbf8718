"""Pure topology and tag-mapping rules, no database: known inputs, known answers."""

from __future__ import annotations

import pytest

from ingest.network.model import RoadLine
from ingest.network.noding import build_topology
from ingest.network.osm_tags import attributes_from_tags, parse_maxspeed, tags_from_attributes


def _line(*coords: tuple[float, float]) -> RoadLine:
    return RoadLine(list(coords))


def test_crossing_lines_are_noded_into_four_segments() -> None:
    topo = build_topology([_line((0, 0), (2, 0)), _line((1, -1), (1, 1))], crossings=True)
    assert topo.crossings_noded == 1
    assert len(topo.segments) == 4
    centre = [n for n in topo.nodes if n.coord == (1.0, 0.0)]
    assert len(centre) == 1 and centre[0].degree == 4 and centre[0].kind == "junction"


def test_t_junction_touch_splits_the_through_line() -> None:
    topo = build_topology([_line((0, 0), (2, 0)), _line((1, 0), (1, 1))], crossings=True)
    assert len(topo.segments) == 3
    assert sorted(n.degree for n in topo.nodes) == [1, 1, 1, 3]


def test_without_crossing_noding_a_bridge_stays_unconnected() -> None:
    topo = build_topology([_line((0, 0), (2, 0)), _line((1, -1), (1, 1))], crossings=False)
    assert len(topo.segments) == 2 and len(topo.nodes) == 4


def test_shared_vertex_splits_and_duplicates_drop() -> None:
    lines = [_line((0, 0), (1, 0), (2, 0)), _line((1, 0), (1, 1)), _line((1, 1), (1, 0))]
    topo = build_topology(lines, crossings=False)
    assert len(topo.segments) == 3
    assert topo.duplicates_dropped == 1


def test_noding_is_idempotent() -> None:
    lines = [_line((0, 0), (2, 0), (2, 2)), _line((1, -1), (1, 3)), _line((0, 1), (3, 1))]
    once = build_topology(lines, crossings=True)
    again = build_topology([RoadLine(s.coords) for s in once.segments], crossings=True)
    assert sorted(map(tuple, (s.coords for s in again.segments))) == \
        sorted(map(tuple, (s.coords for s in once.segments)))
    assert again.crossings_noded == 0


@pytest.mark.parametrize(("value", "kph"), [("50", 50.0), ("30 mph", 48.28), ("walk", 5.0),
                                            ("none", 150.0), ("10 knots", 18.52),
                                            ("DE:urban", None), ("", None)])
def test_maxspeed(value: str, kph: float | None) -> None:
    assert parse_maxspeed(value) == kph


def test_oneway_lanes_and_roundabout() -> None:
    a = attributes_from_tags({"highway": "primary", "lanes": "3", "oneway": "-1"})
    assert (a.oneway, a.lanes_forward, a.lanes_backward) == ("backward", 0, 3)
    r = attributes_from_tags({"highway": "primary", "junction": "roundabout", "lanes": "2"})
    assert (r.oneway, r.is_junction, r.lanes_forward, r.lanes_backward) == ("forward", True, 2, 0)
    two = attributes_from_tags({"highway": "residential", "lanes": "3", "lanes:forward": "2"})
    assert (two.lanes_forward, two.lanes_backward) == (2, 1)
    rev = attributes_from_tags({"highway": "service", "oneway": "reversible", "lit": "yes"})
    assert rev.oneway == "none" and rev.attrs == {"lit": "yes"}


def test_tags_round_trip() -> None:
    tags = {"highway": "secondary", "maxspeed": "30 mph", "lanes": "3", "lanes:forward": "2",
            "name": "Main St; 'quoted'", "surface": "asphalt", "width": "6.5 m",
            "junction": "roundabout", "oneway": "no", "bridge": "yes"}
    a = attributes_from_tags(tags, external_id="w1")
    assert attributes_from_tags(tags_from_attributes(a)) == a
