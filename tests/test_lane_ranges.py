"""A segment's lane ranges read and replaced over the API
(``/collections/{network}-segments/items/{id}/lanes``): rules, roles, If-Match, history and
revert, ``ingest lanes`` keeping them, and the Lanelet2 map drawing the edited lanes as wide
as they were set (lanelet2 loads the map)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from lanelet2 import geometry
from sqlalchemy import text

from app.db.session import session_scope
from app.errors import InvalidValueError
from app.network.lane_ranges import check_ranges, offsets_of
from ingest.lanes.layer import MACHINE, _edited_lanes
from testkit.network_helpers import bearer
from tests.lanelet2_support import export
from tests.test_lanes_ingest import _store_lanes, _straight_road, _width, _width_at


def _range(lo: float, hi: float, f: int, b: int, widths: list[float]) -> dict:
    return {"station_from_m": lo, "station_to_m": hi, "lanes_forward": f, "lanes_backward": b,
            "widths_m": widths}


def test_offsets_put_the_line_between_the_directions_on_the_segment() -> None:
    assert offsets_of([3.0, 3.5, 3.0], 2, 1) == [-6.5, -3.5, 0.0, 3.0]
    assert offsets_of([3.0, 4.0], 2, 0) == [-3.5, -0.5, 3.5]  # one-way: centred


@pytest.mark.parametrize(("body", "where", "says"), [
    ({"ranges": [_range(0, 40, 1, 1, [3, 3]), _range(41, 100, 1, 1, [3, 3])]}, "ranges[1]",
     "station_from_m must be 40"),
    ({"ranges": [_range(0, 90, 1, 1, [3, 3])]}, "ranges[0]", "the segment's length"),
    ({"ranges": [_range(0, 100, 2, 1, [3, 3])]}, "ranges[0]", "width of each of its 3"),
    ({"ranges": [_range(0, 100, 2, 0, [3, 3])]}, "ranges[0]", "do not fit"),
    ({"ranges": [_range(0, 100, 1, 1, [3, 3]) | {"offsets_m": [-3, 0, 4]}]}, "ranges[0]",
     "each lane's width apart"),
    ({"ranges": [_range(0, 100, 1, 1, [3, 3]) | {"colour": "red"}]}, "ranges[0]",
     "unknown member(s) colour"),
    ({"ranges": [_range(0, 100, 1, True, [3, 3])]}, "ranges[0]", "whole numbers"),
    ({"ranges": [_range(0, 100, 1, 1, [3, float("nan")])]}, "ranges[0]", "above 0"),
    ({"lanes": []}, "ranges", "required"),
])
def test_bad_ranges_are_refused_naming_the_range(body: dict, where: str, says: str) -> None:
    with pytest.raises(InvalidValueError) as caught:
        check_ranges(body, 100.0, "none")
    assert says in caught.value.errors[where], caught.value.errors


def test_lane_ranges_edited_over_the_api(database_url: str, tmp_path: Path, client) -> None:
    """A 1+1 road read from the paint becomes 1+1 for 40 m, then 2+1 (3.0 / 3.5 / 3.0 m):
    refused while wrong, stale or not an editor's, with nothing changed; then one new
    version of the segment with its lane counts, a history row, a Lanelet2 map with those
    lanes as wide as set, kept by ``ingest lanes``, and a revert back to the paint's."""
    _straight_road(tmp_path, "range-edit", 48.7)
    _store_lanes("range-edit", [(0, 100, 1, 1, [-3.0, 0.0, 3.0])],
                 [(0, 100, -3.0, 0, "road_edge"), (0, 100, 0.0, 1, "solid"),
                  (0, 100, 3.0, 2, "road_edge")])
    with session_scope() as session:
        sid, net = session.execute(text(
            "SELECT s.id, s.network_id FROM road_segments s JOIN networks n "
            "ON n.id = s.network_id WHERE n.name = 'range-edit'")).one()
        session.execute(text("UPDATE lane_boundaries SET updated_by = :m WHERE segment_id = :s"),
                        {"m": MACHINE, "s": sid})  # as ingest lanes writes them
        assert _edited_lanes(session, net, np.array([sid])) == []
    item = f"/collections/range-edit-segments/items/{sid}"
    got = client.get(item + "/lanes")
    assert got.status_code == 200, got.text
    before = got.json()
    version, length = before["version"], before["length_m"]
    assert got.headers["ETag"] == f'"{version}"'
    assert [(r["lanes_forward"], r["lanes_backward"], r["source"]) for r in before["ranges"]] \
        == [(1, 1, "paint")]
    assert client.get(f"/collections/range-edit-nodes/items/{sid}/lanes").status_code == 405

    body = {"ranges": [_range(0, 40, 1, 1, [3.0, 3.0]),
                       _range(40, length, 2, 1, [3.0, 3.5, 3.0])]}
    editor = {**bearer("editor"), "If-Match": f'"{version}"'}
    assert client.put(item + "/lanes", json=body, headers=bearer("viewer")).status_code == 403
    gap = {"ranges": [body["ranges"][0], {**body["ranges"][1], "station_from_m": 45}]}
    wrong = client.put(item + "/lanes", json=gap, headers=editor)
    assert wrong.status_code == 422 and "ranges[1]" in wrong.json()["errors"], wrong.text
    stale = client.put(item + "/lanes", json=body,
                       headers={**editor, "If-Match": f'"{version - 1}"'})
    assert stale.status_code == 412
    assert client.get(item + "/lanes").json() == before  # nothing half-written

    done = client.put(item + "/lanes", json=body, headers=editor)
    assert done.status_code == 200, done.text
    assert done.headers["ETag"] == f'"{version + 1}"'
    ranges = done.json()["ranges"]
    assert [r["source"] for r in ranges] == ["edited", "edited"]
    assert ranges[1]["offsets_m"] == [-6.5, -3.5, 0.0, 3.0]
    props = client.get(item).json()["properties"]
    assert (props["lanes_forward"], props["lanes_backward"]) == (2, 1)  # the longest range
    last = client.get(item + "/history").json()["edits"][-1]
    assert last["action"] == "lanes" and last["conditional"] is True
    assert len(last["old"]["lane_ranges"]) == 1 and len(last["new"]["lane_ranges"]) == 2

    _, loaded = export("range-edit", tmp_path / "range-edit.osm")
    forward = [ll for ll in loaded.lanelets() if "direction" in ll.attributes
               and ll.attributes["direction"] == "forward"]
    first = min(forward, key=lambda ll: ll.centerline[0].x)
    later = {ll.attributes["lane"]: _width_at(ll, 0.5) for ll in forward  # the new lane
             if ll.centerline[0].x > first.centerline[0].x + 20}          # widens from 0
    assert set(later) == {"1", "2"}, later
    assert abs(later["1"] - 3.0) <= 0.05 and abs(later["2"] - 3.5) <= 0.05, later
    assert abs(_width(first) - 3.0) <= 0.05
    assert all(loaded.graph.getRoute(first, ll) is not None for ll in forward)
    backward = [ll for ll in loaded.lanelets() if "direction" in ll.attributes
                and ll.attributes["direction"] == "backward"]
    assert backward and all(abs(_width(ll) - 3.0) <= 0.05 for ll in backward)

    with session_scope() as session:  # a re-run of ingest lanes keeps a person's ranges
        assert _edited_lanes(session, net, np.array([sid])) == [sid]
    back = client.post(item + f"/revert?to={version}", headers=bearer("editor"))
    assert back.status_code == 200, back.text
    assert client.get(item + "/lanes").json()["ranges"] == before["ranges"]
    props = client.get(item).json()["properties"]
    assert (props["lanes_forward"], props["lanes_backward"]) == (1, 1)
    with session_scope() as session:
        assert _edited_lanes(session, net, np.array([sid])) == []
    assert geometry  # lanelet2's geometry module is what _width measures with
