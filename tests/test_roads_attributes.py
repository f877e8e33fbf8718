"""The attribute rules of extracted roads (``ingest.roads.attributes``), on graphs with known
answers: symmetric lanes, class and speed tables applied and overridable, junction segments
(connectors inside a crossing, roundabouts)."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest

from app.errors import UserError
from app.network.settings import AttributeRules, rules_from
from ingest.roads.attributes import junction_edges, lanes, segment_attributes
from ingest.roads.graph import Edge, Node, RoadGraph


def graph(points: dict[str, tuple[float, float]],
          edges: list[tuple[str, str, float] | tuple[str, str, float, np.ndarray]]) -> RoadGraph:
    """A road graph in 1 m pixels: named nodes, edges (a, b, width[, coords]); straight
    edges unless coordinates are given."""
    ids = {name: i for i, name in enumerate(points)}
    degree: Counter[str] = Counter()
    out = []
    for k, (a, b, width, *shape) in enumerate(edges):
        degree[a] += 1
        degree[b] += 1
        coords = shape[0] if shape else np.array([points[a], points[b]], float)
        length = float(np.linalg.norm(np.diff(coords, axis=0), axis=1).sum())
        out.append(Edge(k, ids[a], ids[b], coords, length, width, 1))
    return RoadGraph([Node(ids[n], xy, degree[n]) for n, xy in points.items()], out)


def comb(main_width: float, side_width: float) -> RoadGraph:
    """A main street A0..A5 (50 m blocks) with a 40 m cul-de-sac at each inner node."""
    points = {f"A{i}": (50.0 * i, 100.0) for i in range(6)}
    points |= {f"S{i}": (50.0 * i, 140.0) for i in range(1, 5)}
    edges = [(f"A{i}", f"A{i + 1}", main_width) for i in range(5)]
    edges += [(f"A{i}", f"S{i}", side_width) for i in range(1, 5)]
    return graph(points, edges)


@pytest.mark.parametrize(("width", "expected"), [
    (2.0, (1, 1, 0)), (7.0, (1, 1, 0)), (9.0, (1, 1, 1)), (10.5, (1, 1, 1)),
    (14.0, (2, 2, 0)), (17.5, (2, 2, 1)), (200.0, (4, 4, 0))])
def test_lanes_are_symmetric_on_two_way_roads(width: float, expected: tuple) -> None:
    assert lanes(width, 3.5) == expected


def test_no_width_gives_more_lanes_one_way_than_the_other() -> None:
    for width in np.arange(0.5, 40.0, 0.1):
        forward, backward, both = lanes(float(width), 3.5)
        assert forward == backward >= 1 and both in (0, 1)
    assert lanes(9.0, 3.0) == (1, 1, 1) and lanes(9.0, 2.25) == (2, 2, 0)  # lane width matters


def test_class_and_speed_follow_width_and_through_routes() -> None:
    attrs = segment_attributes(comb(12.0, 5.0), 1.0, AttributeRules())
    main, sides = attrs[:5], attrs[5:]
    assert [a.through for a in main] == pytest.approx([0.36, 0.84, 1.0, 0.84, 0.36])
    # Wide and central: secondary; wide at the ends of the street: tertiary; narrow: residential.
    assert [a.road_class for a in main] == ["tertiary", "secondary", "secondary", "secondary",
                                            "tertiary"]
    assert {a.road_class for a in sides} == {"residential"}
    assert [a.speed_limit_kph for a in main] == [40.0, 50.0, 50.0, 50.0, 40.0]
    assert {a.speed_limit_kph for a in sides} == {30.0}
    # The same street 8 m wide is no secondary road, whatever its traffic.
    assert {a.road_class for a in segment_attributes(comb(8.0, 5.0), 1.0,
                                                     AttributeRules())[:5]} == {"tertiary"}
    narrow = segment_attributes(comb(3.0, 3.0), 1.0, AttributeRules())
    assert {a.road_class for a in narrow} == {"service"}


def test_class_and_speed_tables_are_overridable() -> None:
    rules = AttributeRules().updated(rules_from({
        "classes": [{"road_class": "primary", "min_through": 0.9},
                    {"road_class": "track", "min_width_m": 6}],
        "speed_kph": {"primary": 70, "track": None}}, "test"))
    attrs = segment_attributes(comb(12.0, 5.0), 1.0, rules)
    assert [a.road_class for a in attrs[:5]] == ["track", "track", "primary", "track", "track"]
    assert {a.road_class for a in attrs[5:]} == {"unclassified"}  # no row matched
    assert attrs[2].speed_limit_kph == 70.0
    assert attrs[0].speed_limit_kph is None  # "track": null = no speed limit
    assert attrs[5].speed_limit_kph == 30.0  # unclassified keeps its default


def test_rule_overrides_merge_and_bad_tables_are_refused() -> None:
    network = rules_from({"speed_kph": {"residential": 25}, "lane_width_m": 3.0}, "network")
    job = rules_from({"speed_kph": {"service": 10}}, "job")
    rules = AttributeRules().updated(network).updated(job)
    assert (rules.speed("residential"), rules.speed("service"), rules.speed("tertiary")) \
        == (25.0, 10.0, 40.0)
    assert rules.lane_width_m == 3.0
    assert rules.overrides() == {"lane_width_m": 3.0,
                                 "speed_kph": {"residential": 25.0, "service": 10.0}}
    for bad, message in [({"speed_kph": {"highway": 30}}, "not a road class"),
                         ({"speed_kph": {"residential": 400}}, "less than or equal to 150"),
                         ({"lane_width_m": 0}, "greater than or equal to 1.5"),
                         ({"classes": []}, "at least 1 item"),
                         ({"lanes": 2}, "Extra inputs")]:
        with pytest.raises(UserError, match=message):
            rules_from(bad, "rules.json")


def test_junction_segments_are_connectors_inside_a_crossing() -> None:
    # Two T-junctions 6 m apart on a main road (a staggered crossing), and a 60 m block.
    points = {"W": (0.0, 50.0), "J1": (40.0, 50.0), "J2": (46.0, 50.0), "J3": (106.0, 50.0),
              "E": (150.0, 50.0), "N": (40.0, 0.0), "S": (46.0, 100.0), "N3": (106.0, 0.0)}
    g = graph(points, [("W", "J1", 7), ("J1", "J2", 7), ("J2", "J3", 7), ("J3", "E", 7),
                       ("J1", "N", 7), ("J2", "S", 7), ("J3", "N3", 7)])
    assert junction_edges(g, 1.0, AttributeRules()) == {1}
    assert junction_edges(g, 1.0, rules_from({"junction_length_m": 70}, "x")) == {1, 2}
    assert [a.is_junction for a in segment_attributes(g, 1.0, AttributeRules())] == [
        False, True, False, False, False, False, False]


def arc(centre: tuple[float, float], radius: float, a0: float, a1: float) -> np.ndarray:
    t = np.linspace(a0, a1, 24)
    return np.column_stack([centre[0] + radius * np.cos(t), centre[1] + radius * np.sin(t)])


def test_roundabout_ring_is_part_of_a_junction_but_a_square_block_is_not() -> None:
    c, r = (100.0, 100.0), 15.0
    ring = {f"R{k}": (c[0] + r * math.cos(k * math.pi / 2), c[1] + r * math.sin(k * math.pi / 2))
            for k in range(4)}
    arms = {f"X{k}": (c[0] + 60 * math.cos(k * math.pi / 2), c[1] + 60 * math.sin(k * math.pi / 2))
            for k in range(4)}
    edges: list = [(f"R{k}", f"R{(k + 1) % 4}", 8.0,
                    arc(c, r, k * math.pi / 2, (k + 1) * math.pi / 2)) for k in range(4)]
    edges += [(f"R{k}", f"X{k}", 8.0) for k in range(4)]
    roundabout = graph(ring | arms, edges)
    assert junction_edges(roundabout, 1.0, AttributeRules()) == {0, 1, 2, 3}

    corners = {"a": (0.0, 0.0), "b": (40.0, 0.0), "c": (40.0, 40.0), "d": (0.0, 40.0)}
    tails = {f"t{n}": (x * 3 - 40, y * 3 - 40) for n, (x, y) in corners.items()}
    block = graph(corners | tails, [("a", "b", 7), ("b", "c", 7), ("c", "d", 7), ("d", "a", 7)]
                  + [(n, f"t{n}", 7) for n in corners])
    assert junction_edges(block, 1.0, AttributeRules()) == set()
