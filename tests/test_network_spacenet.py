"""SpaceNet 3 road labels become real lanes, speeds, one-way flags and road classes."""

from __future__ import annotations

import json
from pathlib import Path

from sqlalchemy import text

from app.db.session import session_scope
from ingest.network import import_network
from ingest.network.properties import attributes_from_properties


def test_spacenet_codes_map_to_columns() -> None:
    two_way = attributes_from_properties(
        {"road_type": "2", "lane_number": "3", "one_way_ty": "2", "paved": "1",
         "speed_mph": 45, "road_id": 17, "bridge_type": "2"})
    assert (two_way.road_class, two_way.oneway) == ("primary", "none")
    assert (two_way.lanes_forward, two_way.lanes_backward) == (2, 1)
    assert abs(two_way.speed_limit_kph - 72.4) < 0.05
    assert two_way.surface == "paved" and two_way.external_id == "17"
    assert two_way.attrs == {"bridge_type": "2"}
    one_way = attributes_from_properties(
        {"road_type": "6", "lane_number": "2", "one_way_ty": "1", "speed_mph": 1000})
    assert (one_way.oneway, one_way.lanes_forward, one_way.lanes_backward) == ("forward", 2, 0)
    assert one_way.speed_limit_kph is None  # out of any sane range: unknown, not invented


def test_spacenet_ground_truth_imports_with_attributes(database_url: str,
                                                       shared_data: Path) -> None:
    path = shared_data / "road_imagery" / "spacenet_vegas" / "AOI_2_Vegas_img0.geojson"
    labels = json.loads(path.read_text())["features"]
    primary = sum(1 for f in labels if f["properties"]["road_type"] == "2")
    with session_scope() as session:
        summary = import_network(session, path, "spacenet-vegas-test")
        rows = session.execute(text(
            "SELECT road_class, speed_limit_kph, lanes_forward + lanes_backward "
            "FROM road_segments WHERE network_id = :n"), {"n": summary.network_id}).all()
    assert summary.lines_read == len(labels)
    classes = {r[0] for r in rows}
    assert classes == {"primary", "unclassified"} and primary > 0
    assert all(r[1] is not None for r in rows)
    assert max(r[2] for r in rows) == 3
