"""Who gives way at a junction in the Lanelet2 map, from the painted stop lines
(:mod:`app.lanelet2.priority`), read back by the official lanelet2 library.

A T junction: a minor road from the west ends at the node where a major road runs south to
north (two segments), each road 1+1 lanes of 3 m with stored paint (as ``ingest lanes``
writes it), and stop lines 10 m before the node where a case says so.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from lanelet2.core import AllWayStop, ManeuverType, RightOfWay
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from testkit.stored_lanes import Range, store_lanes
from tests.lanelet2_support import LoadedMap, export

LENGTH_M = 100.0
ROADS = {"minor": ((-1.0, 0.0), (0.0, 0.0)), "south": ((0.0, -1.0), (0.0, 0.0)),
         "north": ((0.0, 0.0), (0.0, 1.0))}
"""Each segment's ends, in road lengths east and north of the junction."""


def _lonlat(lat0: float, east_m: np.ndarray, north_m: np.ndarray) -> list[list[float]]:
    lon = 16.0 + east_m / (111_320 * np.cos(np.radians(lat0)))
    return np.column_stack([lon, lat0 + north_m / 111_320]).tolist()


def _t_junction(tmp_path: Path, name: str, lat0: float) -> dict[str, int]:
    """Import the T junction at ``lat0``: segment ids by road."""
    features = [{"type": "Feature", "properties": {"name": road, "lanes_forward": 1,
                                                   "lanes_backward": 1},
                 "geometry": {"type": "LineString", "coordinates": _lonlat(
                     lat0, LENGTH_M * np.array([a[0], b[0]]),
                     LENGTH_M * np.array([a[1], b[1]]))}}
                for road, (a, b) in ROADS.items()]
    path = tmp_path / f"{name}.geojson"
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features}))
    result = CliRunner().invoke(main, ["ingest", "network", str(path), "--network", name])
    assert result.exit_code == 0, result.output
    with session_scope() as session:
        return dict(session.execute(text(
            "SELECT s.name, s.id FROM road_segments s JOIN networks n ON n.id = s.network_id "
            "WHERE n.name = :n"), {"n": name}).all())


def _paint(name: str, lat0: float, road: str, segment: int, stop_before_node: bool,
           opening_at: float | None = None) -> None:
    """Store 1+1 lanes of 3 m with edge lines and a solid centre along ``road``, and a stop
    line across the lanes entering the junction 10 m before it when asked; from
    ``opening_at`` metres along the road (west to east on the minor road) a second lane
    entering the junction opens on the right."""
    (ax, ay), (bx, by) = (np.array(p) * LENGTH_M for p in ROADS[road])
    along = np.array([bx - ax, by - ay]) / LENGTH_M
    left = np.array([-along[1], along[0]])

    def line(stations: np.ndarray, offsets: np.ndarray) -> str:
        xy = np.array([ax, ay]) + stations[:, None] * along + offsets[:, None] * left
        coords = _lonlat(lat0, xy[:, 0], xy[:, 1])
        return "LINESTRING(" + ", ".join(f"{x} {y}" for x, y in coords) + ")"

    two_lane = ((-3.0, "road_edge"), (0.0, "solid"), (3.0, "road_edge"))
    ranges: list[Range] = [(0.0, LENGTH_M, 1, 1, [-3.0, 0.0, 3.0])]
    pieces = [(0.0, LENGTH_M, two_lane)]
    if opening_at is not None:
        ranges = [(0.0, opening_at, 1, 1, [-3.0, 0.0, 3.0]),
                  (opening_at, LENGTH_M, 2, 1, [-6.0, -3.0, 0.0, 3.0])]
        pieces = [(0.0, opening_at, two_lane), (opening_at, LENGTH_M, (
            (-6.0, "road_edge"), (-3.0, "dashed"), (0.0, "solid"), (3.0, "road_edge")))]
    rows = [(line(np.linspace(lo, hi, 12), np.full(12, o)), kind, k, o, lo, hi)
            for lo, hi, lines in pieces for k, (o, kind) in enumerate(lines)]
    if stop_before_node:
        # The lanes entering the node: forward ones (right) where the road ends there.
        ends_at_node = road != "north"
        station = LENGTH_M - 10.0 if ends_at_node else 10.0
        across = np.array([-3.0, 0.0]) if ends_at_node else np.array([0.0, 3.0])
        rows.append((line(np.full(2, station), across), "stop_line", None,
                     float(across.mean()), station - 0.1, station + 0.1))
    store_lanes(name, segment, ranges, rows)


def _junction_map(tmp_path: Path, name: str, lat0: float, stops: set[str],
                  painted: set[str], minor_opening_at: float | None = None
                  ) -> tuple[LoadedMap, dict[str, int]]:
    ids = _t_junction(tmp_path, name, lat0)
    for road in sorted(painted):
        _paint(name, lat0, road, ids[road], road in stops,
               minor_opening_at if road == "minor" else None)
    _, loaded = export(name, tmp_path / f"{name}.osm")
    return loaded, ids


def _elements(loaded: LoadedMap, subtype: str) -> list:
    return [re for re in loaded.map.regulatoryElementLayer
            if re.attributes["subtype"] == subtype]


@pytest.mark.usefixtures("database_url")
def test_a_stop_line_on_the_minor_road_gives_the_major_road_the_right_of_way(
        tmp_path: Path) -> None:
    loaded, ids = _junction_map(tmp_path, "give-way", 48.71, {"minor"},
                                {"minor", "south", "north"})
    (element,) = _elements(loaded, "right_of_way")
    assert isinstance(element, RightOfWay)
    (yielding,) = element.yieldLanelets()
    assert yielding.attributes["segment_id"] == str(ids["minor"])
    assert element.getManeuver(yielding) == ManeuverType.Yield
    priority = element.rightOfWayLanelets()
    assert sorted(ll.attributes["segment_id"] for ll in priority) == sorted(
        [str(ids["south"]), str(ids["north"])])
    assert all(element.getManeuver(ll) == ManeuverType.RightOfWay for ll in priority)
    assert element.stopLine.attributes["type"] == "stop_line"
    for ll in [yielding, *priority]:  # the last lanelet of its approach, referencing it
        assert element.id in [re.id for re in ll.regulatoryElements]
        assert any(loaded.graph.following(ll)) and all(
            "turn_direction" in nxt.attributes for nxt in loaded.graph.following(ll))
    assert len(_elements(loaded, "traffic_sign")) == 1  # the stop sign stays


@pytest.mark.usefixtures("database_url")
def test_a_stop_line_before_a_lane_that_opens_still_gives_way(tmp_path: Path) -> None:
    """The minor road's stop line 10 m before the junction, and a turning lane opening 3 m
    after it: the stop is followed through the opening to the junction, and both lanes that
    enter it yield."""
    loaded, ids = _junction_map(tmp_path, "give-way-opening", 48.74, {"minor"},
                                {"minor", "south", "north"}, minor_opening_at=93.0)
    (element,) = _elements(loaded, "right_of_way")
    yielding = element.yieldLanelets()
    assert len(yielding) == 2
    assert all(ll.attributes["segment_id"] == str(ids["minor"])
               and element.getManeuver(ll) == ManeuverType.Yield for ll in yielding)
    assert len(element.rightOfWayLanelets()) == 2
    assert element.stopLine.attributes["type"] == "stop_line"


@pytest.mark.usefixtures("database_url")
def test_stop_lines_on_every_approach_are_an_all_way_stop(tmp_path: Path) -> None:
    roads = {"minor", "south", "north"}
    loaded, ids = _junction_map(tmp_path, "all-way", 48.72, roads, roads)
    assert _elements(loaded, "right_of_way") == []
    (element,) = _elements(loaded, "all_way_stop")
    assert isinstance(element, AllWayStop)
    lanelets = element.lanelets()
    assert sorted(ll.attributes["segment_id"] for ll in lanelets) == sorted(
        str(i) for i in ids.values())
    assert len(element.stopLines()) == len(lanelets) == 3
    assert len(element.trafficSigns()) == 3
    assert all(element.id in [re.id for re in ll.regulatoryElements] for ll in lanelets)


@pytest.mark.usefixtures("database_url")
def test_approaches_whose_paint_was_not_read_are_given_no_priority(tmp_path: Path) -> None:
    """Only the minor road's paint was read: nothing is known of the major road's lanes,
    so no element says it has the right of way (the stop sign stays)."""
    loaded, _ = _junction_map(tmp_path, "unread", 48.73, {"minor"}, {"minor"})
    assert _elements(loaded, "right_of_way") == [] and _elements(loaded, "all_way_stop") == []
    assert len(_elements(loaded, "traffic_sign")) == 1
