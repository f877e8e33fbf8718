"""The cuts across the road (ingest.lanes.across) on marking lines drawn here, in metres."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from ingest.lanes.across import sections


def arc(radius: float, start: float, stop: float, step: float = 0.05) -> np.ndarray:
    """Points every ``step`` m on a circle round the origin, anticlockwise from metres
    ``start`` to ``stop`` along it."""
    s = np.arange(start, stop + step / 2, step)
    return np.column_stack([radius * np.cos(s / radius), radius * np.sin(s / radius)])


def test_a_dashed_line_on_a_bend_is_cut_where_its_paint_runs() -> None:
    """3 m dashes 6 m apart on a 38.5 m radius, joined across each gap by a chord (as the
    classification joins them): the chord runs up to 0.12 m inside the painted arc, which
    made a 3.0 m lane 0.12 m wrong at every gap of a bend (29 % of the synthetic drive's cuts
    before). Cut from a path at 40 m radius, the line must be met where the paint would be."""
    dashes = [arc(38.5, a, a + 3.0) for a in np.arange(0.0, 60.0, 9.0)]
    dashed = shapely.LineString(np.vstack(dashes))  # consecutive dashes joined straight
    solid = shapely.LineString(arc(41.5, 0.0, 65.0))
    path = shapely.LineString(arc(40.0, 0.0, 60.0))  # anticlockwise: left is inwards
    cuts = sections(path, [(dashed, "dashed"), (solid, "solid")], step_m=0.5)
    inner = [c for c in cuts if 2.0 < c.station_m < 56.0]
    assert len(inner) > 100
    for cut in inner:
        assert cut.kinds == ("solid", "dashed")
        assert cut.offsets == pytest.approx((-1.5, 1.5), abs=0.02), cut


def test_a_closed_reference_starting_in_a_gap_is_cut_the_same() -> None:
    """A drive round a ring (the reference closed) whose start lies in a gap between dashes:
    the gap's ends are near the reference's end and its start, and the join across that gap
    must not be redrawn the long way round the ring (it crossed every cut at offsets between
    the two)."""
    dashes = [arc(38.5, a, a + 3.0) for a in np.arange(0.0, 2 * np.pi * 38.5 - 3.0, 9.0)]
    dashed = shapely.LineString(np.vstack(dashes))
    start = 4.5 / 38.5 * 40.0
    ring = arc(40.0, start, start + 2 * np.pi * 40.0 - 0.1)
    cuts = sections(shapely.LineString([*ring, ring[0]]), [(dashed, "dashed")], step_m=0.5)
    met = [c for c in cuts if c.offsets]
    assert len(met) > 400
    assert all(c.offsets == pytest.approx((1.5,), abs=0.02) for c in met)


def test_a_line_unseen_for_a_few_metres_is_bridged_but_one_that_ends_is_not() -> None:
    """A far edge line found in two pieces with 4 m unseen between them is one line across
    the gap (the cuts there meet it, at its offset); a lane line that ends 25 m along (a lane
    that ends) is not carried on."""
    def along(y: float, x0: float, x1: float) -> shapely.LineString:
        return shapely.LineString([(x, y) for x in np.arange(x0, x1 + 0.01, 0.1)])

    lines = [(along(3.0, 0, 15), "road_edge"), (along(3.05, 19, 40), "road_edge"),
             (along(-0.5, 0, 25), "dashed"), (along(-4.0, 0, 40), "road_edge")]
    cuts = {c.station_m: c for c in sections(shapely.LineString([(0, 0), (40, 0)]), lines)}
    for s in np.arange(15.25, 19.0, 0.5):
        assert len(cuts[s].offsets) == 3 and cuts[s].offsets[-1] == pytest.approx(3.025,
                                                                                 abs=0.03)
    for s in np.arange(26.25, 40.0, 0.5):
        assert cuts[s].offsets == pytest.approx((-4.0, 3.05), abs=0.01)
