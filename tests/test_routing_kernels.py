"""The compiled routing kernels (app.routing.native) against independent references: GEOS's
distance and Douglas-Peucker (shapely), the ``polyline`` package's encoder, and the cut lines
of :func:`app.routing.geometry.cut_with_fractions`, on random synthetic lines with known
edge cases (antimeridian, zero-length edges, points off the globe, rounding halves)."""

from __future__ import annotations

import itertools

import numpy as np
import polyline
import pytest
import shapely

from app.routing.encoded_polyline import encode
from app.routing.geometry import cut_with_fractions, point_at, vertex_fractions
from app.routing.junctions import _crossings
from app.routing.nearby import LARGE_CELLS, Grid, _near, _nearest_on_line, _pairs, _scale
from app.routing.overview import MERCATOR_R, PIXEL_M, fitted_zoom, simplify
from app.routing.steps import modifier
from app.routing.trace import _gathered


def _lines(rng: np.random.Generator, n: int, lon: float = 1.52, lat: float = 42.5
           ) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random polylines of 1-12 vertices near (lon, lat), flat with offsets; one in
    five repeats a vertex (a zero-length edge)."""
    parts = []
    for _ in range(n):
        k = int(rng.integers(1, 13))
        walk = np.cumsum(rng.normal(0.0, 2e-4, (k, 2)), axis=0) + np.array([lon, lat])
        if k > 2 and rng.random() < 0.2:
            walk[1] = walk[0]
        parts.append(walk + rng.normal(0.0, 1e-3, 2))
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in parts])]).astype(np.int64)
    return np.concatenate(parts), offsets


def _bbox(coords: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    return np.array([[*coords[a:b].min(axis=0), *coords[a:b].max(axis=0)]
                     for a, b in itertools.pairwise(offsets)])


def test_nearest_on_line_is_geos_distance_in_the_local_frame() -> None:
    rng = np.random.default_rng(7)
    coords, offsets = _lines(rng, 60)
    fracs = vertex_fractions(coords, offsets)
    bbox = _bbox(coords, offsets)
    points = coords[rng.integers(0, len(coords), 25)] + rng.normal(0.0, 3e-4, (25, 2))
    for p, r in itertools.product(points, range(60)):
        east, north = _scale(p[1])
        distance, fraction = _nearest_on_line(p[0], p[1], east, north, r, offsets, coords,
                                              fracs, bbox)
        line = coords[offsets[r]:offsets[r + 1]]
        local = (line - p) * [east, north]
        geom = shapely.LineString(local) if len(local) > 1 else shapely.Point(local[0])
        assert distance == pytest.approx(shapely.distance(geom, shapely.Point(0, 0)),
                                         rel=1e-9, abs=1e-9)
        # The fraction names the point measured: at that distance from the query point.
        at = np.subtract(point_at(line, fracs[offsets[r]:offsets[r + 1]], fraction), p) * \
            [east, north]
        assert np.hypot(*at) == pytest.approx(distance, abs=1e-6)


def test_nearest_on_line_across_the_antimeridian_and_off_the_globe() -> None:
    coords = np.array([[179.9999, 10.0], [-179.9999, 10.0], [0.0, 95.0], [1.0, 95.0]])
    offsets = np.array([0, 2, 4], np.int64)
    fracs = np.array([0.0, 1.0, 0.0, 1.0])
    east, north = _scale(10.0001)
    bbox = _bbox(coords, offsets)
    distance, fraction = _nearest_on_line(180.0, 10.0001, east, north, 0, offsets, coords,
                                          fracs, bbox)
    assert distance == pytest.approx(0.0001 * north, rel=1e-9)  # the short way round
    assert fraction == pytest.approx(0.5)
    distance, fraction = _nearest_on_line(180.0, 10.0001, east, north, 1, offsets, coords,
                                          fracs, bbox)
    assert np.isnan(distance) and np.isnan(fraction)  # latitude 95: not on the globe


def _meeting(boxes: np.ndarray, q: np.ndarray) -> set[int]:
    """Indices of ``boxes`` meeting ``q``, edges included, read one by one."""
    return {i for i, b in enumerate(boxes)
            if b[0] <= q[2] and b[2] >= q[0] and b[1] <= q[3] and b[3] >= q[1]}


def test_grid_finds_every_box_meeting_a_query_once() -> None:
    rng = np.random.default_rng(11)
    lo = rng.uniform(0.0, 10.0, (400, 2))
    boxes = np.hstack([lo, lo + rng.exponential(0.2, (400, 2))])
    boxes[:5] = [0.5, 0.5, 9.5, 9.5]  # over more than LARGE_CELLS cells of ~0.5
    boxes[5, 2:] = boxes[5, :2]  # a point
    boxes[6] = [np.nan, 1.0, 2.0, 2.0]  # in no cell, meets nothing
    boxes[7] = [10.5, 10.5, 10.6, 10.6]  # beside the rest
    grid = Grid.of(boxes)
    assert len(grid.large) == 5 and (grid.dims[0] * grid.dims[1]) < 4 * len(boxes)
    assert set(grid.large.tolist()) == set(range(5))
    assert LARGE_CELLS < 18 * 18  # the premise: a 9 x 9 box over cells of ~0.5
    lo = rng.uniform(-2.0, 12.0, (60, 2))
    queries = np.vstack([np.hstack([lo, lo + rng.exponential(0.5, (60, 2))]),
                         [[-50.0, -50.0, 50.0, 50.0], [3.0, 3.0, 3.0, 3.0],
                          [30.0, 30.0, 31.0, 31.0], [np.nan, 0.0, 1.0, 1.0],
                          [*boxes[5, :2], *boxes[5, :2]], [10.55, 10.55, 10.7, 10.7]]])
    ids = np.arange(len(boxes), dtype=np.int64) * 10
    stale = np.array([30, 40, 50], np.int64)  # edited since: their current boxes count
    current = np.delete(ids, [4])  # id 40 deleted since the grid was built
    bbox = np.delete(boxes, [4], axis=0).copy()
    bbox[3] = [9.0, 9.0, 9.5, 9.5]  # id 30 moved (row 3 once id 40 is gone)
    which, rows = _pairs(queries, grid.frame, grid.dims, grid.start, grid.items, grid.large,
                         ids, stale, current, bbox)
    assert len(set(zip(which.tolist(), rows.tolist(), strict=True))) == len(rows)  # once each
    for i, q in enumerate(queries):
        assert set(rows[which == i].tolist()) == _meeting(bbox, q), q


def test_near_is_every_segment_measured_and_ordered_one_by_one() -> None:
    rng = np.random.default_rng(5)
    coords, offsets = _lines(rng, 300)
    coords = coords + rng.uniform(-0.02, 0.02, (1, 2))
    fracs = vertex_fractions(coords, offsets)
    bbox = np.asfortranarray(_bbox(coords, offsets))  # as the graph holds it
    points = np.vstack([coords[rng.integers(0, len(coords), 40)] +
                        rng.normal(0.0, 2e-4, (40, 2)), coords[offsets[3]]])  # one at a vertex
    reach = rng.uniform(10.0, 400.0, len(points))
    grid = Grid.of(bbox)
    ids = np.arange(len(bbox), dtype=np.int64) * 3 + 1
    which, rows, distance, fraction = _near(
        points, reach, grid.frame, grid.dims, grid.start, grid.items, grid.large, ids,
        np.zeros(0, np.int64), ids, bbox, offsets, coords, fracs)
    for p, (x, y) in enumerate(points):
        east, north = _scale(y)
        measured = [(r, *_nearest_on_line(x, y, east, north, r, offsets, coords, fracs, bbox))
                    for r in range(len(bbox))]
        near = [(r, round(d, 6), f) for r, d, f in measured if d <= reach[p]]
        near.sort(key=lambda h: (h[1], 0.0 < h[2] < 1.0, ids[h[0]]))
        mine = which == p
        assert rows[mine].tolist() == [h[0] for h in near]
        assert distance[mine].tolist() == pytest.approx([h[1] for h in near], abs=1e-9)
        assert fraction[mine].tolist() == [h[2] for h in near]
    assert (which == len(points) - 1).sum() >= 2  # segments meeting at that vertex: a tie


@pytest.mark.parametrize("n", [3, 10, 200, 3000])
def test_simplify_keeps_the_vertices_geos_keeps(n: int) -> None:
    rng = np.random.default_rng(n)
    t = np.linspace(0.0, 1.0, n)  # a winding road with centimetre jitter
    lonlat = np.column_stack([1.52 + 0.01 * t, 42.5 + 0.002 * np.sin(6 * t)]) + \
        rng.normal(0.0, 1e-7, (n, 2))
    x = np.radians(lonlat[:, 0]) * MERCATOR_R
    y = np.log(np.tan(np.pi / 4 + np.radians(lonlat[:, 1]) / 2)) * MERCATOR_R
    tolerance = PIXEL_M[fitted_zoom(max(np.ptp(x), np.ptp(y)))]
    geos = shapely.simplify(shapely.linestrings(x, y, np.arange(n, dtype=float)), tolerance,
                            preserve_topology=False)
    kept = shapely.get_coordinates(geos, include_z=True)[:, 2].astype(int)
    assert np.array_equal(simplify(lonlat), lonlat[kept])
    assert n < 200 or len(kept) < n / 2  # it does thin


def test_simplify_leaves_lines_off_the_globe_and_short_ones() -> None:
    beyond = np.array([[0.0, 0.0], [0.0, 91.0], [1.0, 1.0]])
    assert simplify(beyond) is beyond
    two = np.array([[0.0, 0.0], [1.0, 1.0]])
    assert simplify(two) is two


@pytest.mark.parametrize("precision", [5, 6])
def test_encode_is_the_polyline_package(precision: int) -> None:
    rng = np.random.default_rng(precision)
    lonlat = np.column_stack([rng.uniform(-180, 180, 300), rng.uniform(-90, 90, 300)])
    halves = np.array([[-179.9999995, 89.9999995], [0.0000005, -0.0000005],
                       [-0.0000015, 0.0000025], [0.0, 0.0]])
    for line in (lonlat, halves, lonlat[:1]):
        assert encode(line, precision) == polyline.encode([(y, x) for x, y in line], precision)
    assert encode(np.zeros((0, 2)), precision) == ""


def test_gathered_is_the_pieces_cut_lines_joined() -> None:
    rng = np.random.default_rng(3)
    coords, offsets = _lines(rng, 40)
    fracs = vertex_fractions(coords, offsets)
    for _ in range(50):
        m = int(rng.integers(1, 8))
        rows = rng.integers(0, 40, m).astype(np.int64)
        f_from = rng.choice([0.0, 1.0], m)
        f_to = 1.0 - f_from
        f_from[0], f_to[-1] = rng.uniform(0, 1), rng.uniform(0, 1)  # the cut ends
        start = np.array(point_at(coords[offsets[rows[0]]:offsets[rows[0] + 1]],
                                  fracs[offsets[rows[0]]:offsets[rows[0] + 1]], f_from[0]))
        out, starts = _gathered(rows, f_from, f_to, offsets, coords, fracs, start)
        expected = [start]
        first = [0]
        for r, a, b in zip(rows, f_from, f_to, strict=True):
            lo, hi = offsets[r], offsets[r + 1]
            expected.extend(cut_with_fractions(coords[lo:hi], fracs[lo:hi], a, b)[0][1:])
            first.append(len(expected) - 1)
        assert np.array_equal(out, np.array(expected))
        assert starts.tolist() == first


@pytest.mark.parametrize(("before", "after", "expected"), [
    (0.0, 0.0, "straight"), (10.0, 40.0, "straight"), (350.0, 20.0, "straight"),
    (0.0, 30.5, "slight right"), (0.0, 60.0, "slight right"), (300.0, 0.0, "slight right"),
    (0.0, 61.0, "right"), (90.0, 210.0, "right"), (0.0, 121.0, "sharp right"),
    (0.0, 169.0, "sharp right"), (0.0, 170.0, "uturn"), (0.0, 180.0, "uturn"),
    (0.0, 190.0, "uturn"), (0.0, 315.0, "slight left"), (10.0, 280.0, "left"),
    (0.0, 200.0, "sharp left"), (0.0, 329.5, "slight left"), (0.0, 330.0, "straight"),
])
def test_turn_modifiers_follow_osrms_angles(before: float, after: float, expected: str) -> None:
    assert modifier(before, after) == expected


def test_crossings_are_each_nodes_roads_read_one_by_one() -> None:
    rng = np.random.default_rng(3)
    n_nodes, n_rows = 40, 70
    degree = rng.integers(1, 6, n_nodes)
    offsets = np.concatenate([[0], np.cumsum(degree)]).astype(np.int64)
    row = rng.integers(0, n_rows, offsets[-1]).astype(np.int64)
    at_target = rng.random(offsets[-1]) < 0.5
    bearing = rng.integers(0, 360, offsets[-1]).astype(np.int64)
    oneway = rng.integers(-1, 2, n_rows).astype(np.int8)
    nodes = rng.integers(0, n_nodes, 30).astype(np.int64)
    # Arrive and leave by one of the node's roads, or (one in five) by a road not there.
    pick = [int(offsets[k] + rng.integers(0, degree[k])) for k in nodes]
    came_rows = np.where(rng.random(30) < 0.2, n_rows, row[pick]).astype(np.int64)
    came_at = at_target[pick].copy()
    pick = [int(offsets[k] + rng.integers(0, degree[k])) for k in nodes]
    leaves_rows, leaves_at = row[pick].astype(np.int64), at_target[pick].copy()

    out_offsets, rows, bearings, entry, came, leaves = _crossings(
        offsets, row, at_target, bearing, oneway, nodes, came_rows, came_at, leaves_rows,
        leaves_at)
    assert out_offsets[0] == 0
    for k, node in enumerate(nodes):
        roads = range(offsets[node], offsets[node + 1])
        at = slice(out_offsets[k], out_offsets[k + 1])
        assert rows[at].tolist() == [row[j] for j in roads]
        assert bearings[at].tolist() == [bearing[j] for j in roads]
        # May be driven into: away from the node along the road's one-way direction.
        assert entry[at].tolist() == [bool(oneway[row[j]] <= 0 if at_target[j]
                                           else oneway[row[j]] >= 0) for j in roads]
        for index, (r, t) in ((came[k], (came_rows[k], came_at[k])),
                              (leaves[k], (leaves_rows[k], leaves_at[k]))):
            matches = [i for i, j in enumerate(roads) if (row[j], at_target[j]) == (r, t)]
            assert index == (matches[-1] if matches else -1)
