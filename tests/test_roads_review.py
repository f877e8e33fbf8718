"""Review edits are labels: the edits a map team made to a network extracted from a layer,
through the real editing API, read back as the layer's road / not-road lines."""

from __future__ import annotations

from typing import Any

from shapely.geometry import LineString, shape

from app.db.session import session_scope
from ingest.roads.review import review_labels
from testkit.network_helpers import bearer, grid_network

LAYER = "review-layer"


def _line(*coords: tuple[float, float]) -> dict[str, Any]:
    return {"type": "Feature", "properties": {"name": "Drawn"},
            "geometry": {"type": "LineString", "coordinates": [list(c) for c in coords]}}


def _segment(client, items: str, start: tuple[float, float], end: tuple[float, float]
             ) -> dict[str, Any]:
    """The network's segment from ``start`` to ``end`` (either way round)."""
    for feature in client.get(items, params={"limit": 100}).json()["features"]:
        ends = {tuple(feature["geometry"]["coordinates"][0]),
                tuple(feature["geometry"]["coordinates"][-1])}
        if ends == {start, end}:
            return feature
    raise AssertionError(f"no segment {start} -> {end}")


def _same(a: Any, b: LineString) -> bool:
    return shape(a).equals_exact(b, 1e-9) or shape(a).reverse().equals_exact(b, 1e-9)


def test_deleted_and_kept_segments_become_not_road_and_road_lines(client) -> None:
    editor = bearer("editor")
    net = grid_network(attrs={"extracted_from": LAYER, "classifier": "model"})
    items = f"/collections/{net.network}-segments/items"
    with session_scope() as session:
        assert review_labels(session, LAYER).count == 0  # extracted, not reviewed yet

    false_road = _segment(client, items, (10.0, 50.0), (10.001, 50.0))
    assert client.delete(f"{items}/{false_road['id']}", headers=editor).status_code == 204
    kept = _segment(client, items, (10.001, 50.001), (10.002, 50.001))
    confirmed = client.patch(f"{items}/{kept['id']}", json={"road_class": "service"},
                             headers=editor)
    assert confirmed.status_code == 200, confirmed.text
    bent = _segment(client, items, (10.002, 50.0), (10.002, 50.001))
    bent_line = [[10.002, 50.0], [10.00203, 50.0005], [10.002, 50.001]]
    moved = client.patch(f"{items}/{bent['id']}", headers=editor, json={
        "geometry": {"type": "LineString", "coordinates": bent_line}})
    assert moved.status_code == 200, moved.text
    drawn = client.post(items, json=_line((10.0, 50.001), (10.001, 50.002)), headers=editor)
    assert drawn.status_code == 201, drawn.text
    # A road a person drew and deleted again says nothing; nor does a network extracted from
    # another layer.
    undone = client.post(items, json=_line((10.001, 50.0), (10.002, 50.001)), headers=editor)
    assert client.delete(f"{items}/{undone.json()['id']}", headers=editor).status_code == 204
    other = grid_network(attrs={"extracted_from": "another-layer"})
    other_items = f"/collections/{other.network}-segments/items"
    gone = _segment(client, other_items, (10.0, 50.0), (10.001, 50.0))
    assert client.delete(f"{other_items}/{gone['id']}", headers=editor).status_code == 204

    with session_scope() as session:
        review = review_labels(session, LAYER)
    assert (review.deleted, review.drawn, review.moved, review.confirmed) == (1, 1, 1, 1)
    assert review.networks == (net.network,)
    assert review.describe() == (f"4 review labels from network {net.network} "
                                 "(1 deleted, 1 drawn, 1 moved, 1 confirmed)")
    sample = review.sample
    assert sample.not_road_beyond_m is None  # partial: says nothing about the rest
    assert len(sample.not_road_lines) == 1
    assert _same(false_road["geometry"], sample.not_road_lines[0])
    roads = sample.road_lines
    assert len(roads) == 3
    assert any(_same(kept["geometry"], r) for r in roads)
    assert any(r.equals_exact(LineString(bent_line), 1e-9) for r in roads)  # as moved to
    assert any(_same(drawn.json()["geometry"], r) for r in roads)


def test_a_layer_nothing_was_extracted_from_has_no_review(database_url: str) -> None:
    with session_scope() as session:
        review = review_labels(session, "never-extracted")
    assert review.sample.empty and review.count == 0
    assert review.describe() == "0 review labels from no network extracted from the layer"
