"""Lanes from the paint, stored and mapped: ``ugvmap ingest lanes`` on the IPM mosaic of a short
synthetic multi-lane drive (:class:`ingest.ipm.synthetic.LanePaint`: 2+2 lanes of 3.5 / 3.0 /
3.25 / 3.75 m from the right edge, edge lines, a solid yellow centre, dashed lane lines, a stop
line across the forward lanes), over a network imported along the road's true centre, then
``export network --format lanelet2`` loaded by the official lanelet2 library.

The drive is 12 frames (about 14 m driven; the mosaic shows some 30 m of road), the cheapest
that still shows every line and the stop line.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import mapbox_vector_tile
import morecantile
import numpy as np
import pytest
import shapely
from click.testing import CliRunner
from lanelet2 import geometry, traffic_rules
from pyproj import Transformer
from rasterio.transform import from_origin
from sqlalchemy import text

from app.db.session import session_scope
from cli.main import main
from ingest.ipm.synthetic import Camera, Drive, LanePaint, frame_times, write_drive
from ingest.lanes.assign import Paint, boundaries, lane_ranges
from ingest.queue import tasks
from testkit.network_helpers import bearer
from testkit.raster_synth import UTM33, utm_origin, write_tif
from testkit.stored_lanes import store_lanes
from tests.lanelet2_support import LoadedMap, export
from tests.test_ipm_drive import GRID_ARGS

PAINT = LanePaint((3.5, 3.0, 3.25, 3.75), 2, stop_at_m=12.0)
DRIVE = Drive.in_lane(PAINT, 1)
FRAMES = 12
WIDTHS = {("forward", 1): 3.5, ("forward", 2): 3.0, ("backward", 1): 3.75,
          ("backward", 2): 3.25}
"""Truth per (direction, lane from the right of that direction)."""


def run(*args: str) -> str:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 0, result.output
    return result.output


def refused(*args: str) -> str:
    result = CliRunner().invoke(main, list(args))
    assert result.exit_code == 1, result.output
    return result.output


def centreline(from_m: float, to_m: float) -> list[list[float]]:
    """The road's true centre (lon/lat) from ``from_m`` to ``to_m`` along the drive."""
    radius = DRIVE.radius_m + DRIVE.road_offset_m
    az = np.radians(DRIVE.start_deg) + np.linspace(from_m, to_m, 60) / DRIVE.radius_m
    lon, lat = DRIVE.to_lonlat(radius * np.sin(az), radius * np.cos(az))
    return np.column_stack([lon, lat]).tolist()


def ingest_drive(folder: Path, drive: Drive, frames: int, name: str, until_m: float,
                 lanes: int) -> str:
    """The drive rendered into ``folder`` and ingested as layer ``{name}-drive``, a network
    ``{name}-road`` along the road's true centre from 6 m behind the drive's start to
    ``until_m`` (``lanes`` each way), and what ``ingest lanes`` said."""
    paths = write_drive(folder, drive, Camera(), frame_times(frames))
    run("ingest", "ipm", str(paths["frames"]), "--poses", str(paths["poses"]), "--calib",
        str(paths["calib"]), "--layer", f"{name}-drive", *GRID_ARGS)
    road = folder / "road.geojson"
    road.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"lanes_forward": lanes, "lanes_backward": lanes},
        "geometry": {"type": "LineString", "coordinates": centreline(-6.0, until_m)}}]}))
    run("ingest", "network", str(road), "--network", f"{name}-road")
    return run("ingest", "lanes", "--layer", f"{name}-drive", "--network", f"{name}-road")


@pytest.fixture(scope="module")
def drive(database_url: str, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The drive's layer, a network along its road, and what ``ingest lanes`` said."""
    folder = tmp_path_factory.mktemp("lane-drive")
    return {"output": ingest_drive(folder, DRIVE, FRAMES, "lane", 24.0, 1),
            "folder": str(folder)}


def stored(network: str) -> tuple[list, list]:
    with session_scope() as session:
        ranges = session.execute(text(
            "SELECT l.* FROM segment_lanes l JOIN networks n ON n.id = l.network_id "
            "WHERE n.name = :n ORDER BY l.station_from_m"), {"n": network}).all()
        rows = session.execute(text(
            "SELECT b.kind, b.colour, b.position, b.offset_m, b.source, b.station_from_m, "
            "b.station_to_m FROM lane_boundaries b JOIN networks n ON n.id = b.network_id "
            "WHERE n.name = :n ORDER BY b.position, b.station_from_m"), {"n": network}).all()
    return ranges, rows


def test_ingest_lanes_stores_the_lanes_and_boundaries_of_the_paint(drive: dict[str, str]
                                                                  ) -> None:
    assert "lanes from the paint of layer lane-drive on 1 of 1 segments" in drive["output"]
    ranges, rows = stored("lane-road")
    assert len(ranges) == 1 and (ranges[0].lanes_forward, ranges[0].lanes_backward) == (2, 2)
    assert ranges[0].station_from_m == 0 and ranges[0].station_to_m > 29
    assert np.allclose(ranges[0].widths_m, [3.5, 3.0, 3.25, 3.75], atol=0.15), ranges[0]
    painted = {(r.position, r.kind, r.colour) for r in rows if r.source == "paint"}
    assert painted >= {(0, "road_edge", "white"), (1, "dashed", "white"),
                       (2, "solid", "yellow"), (3, "dashed", "white"),
                       (4, "road_edge", "white")}, painted
    assert not {(p, k) for p, k, _ in painted} - {(0, "road_edge"), (1, "dashed"),
                                                   (2, "solid"), (3, "dashed"),
                                                   (4, "road_edge"), (None, "stop_line")}
    stops = [r for r in rows if r.kind == "stop_line"]
    assert len(stops) == 1 and stops[0].offset_m < 0  # across the forward (right) lanes
    assert all(r.kind != "stop_line" or r.position is None for r in rows)
    with session_scope() as session:
        job = session.execute(text("SELECT status, progress FROM ingest_jobs "
                                   "WHERE kind = 'ingest-lanes' ORDER BY id DESC")).first()
        segment = session.execute(text(
            "SELECT s.lanes_forward, s.lanes_backward, s.version, e.action, e.old, e.new "
            "FROM road_segments s JOIN networks n ON n.id = s.network_id JOIN segment_edits e "
            "ON e.segment_id = s.id WHERE n.name = 'lane-road'")).one()
    assert job is not None and tuple(job) == ("succeeded", 1.0)
    # imported as 1+1: routing's lane counts now follow the paint, as a revertable edit
    assert tuple(segment) == (2, 2, 2, "lanes-from-paint",
                              {"lanes_forward": 1, "lanes_backward": 1},
                              {"lanes_forward": 2, "lanes_backward": 2})
    assert "lane counts of 1 segments set from the paint" in drive["output"]


def _bound(line) -> tuple[str, str, str]:
    a = line.attributes
    return (a["type"], a["subtype"] if "subtype" in a else "",  # noqa: SIM401 (no .get)
            a["color"] if "color" in a else "")  # noqa: SIM401


def _width(ll) -> float:
    """Median width of a lanelet across its centreline."""
    c = ll.centerline
    inner = [c[i] for i in range(1, len(c) - 1)] or [c[0]]
    return float(np.median([geometry.distance(ll.leftBound, p)
                            + geometry.distance(ll.rightBound, p) for p in inner]))


def _exported(drive: dict[str, str]) -> LoadedMap:
    _, loaded = export("lane-road", Path(drive["folder"]) / "lanes.osm")
    return loaded


def test_lanelet2_bounds_are_the_painted_lines(drive: dict[str, str]) -> None:
    loaded = _exported(drive)  # lanelet2 loads it with no error, every lanelet as written
    lanelets = loaded.lanelets()
    assert len(lanelets) == 8  # 2+2 lanes, cut in two at the stop line
    for ll in lanelets:
        a = ll.attributes
        lane = (a["direction"], int(a["lane"]))
        assert abs(_width(ll) - WIDTHS[lane]) <= 0.15, (lane, _width(ll))
        outer = ll.rightBound
        assert _bound(outer) == ("road_border", "", "") if lane[1] == 1 else \
            _bound(outer) == ("line_thin", "dashed", "white")
        inner = ll.leftBound
        assert _bound(inner) == ("line_thin", "dashed", "white") if lane[1] == 1 else \
            _bound(inner) == ("line_thin", "solid", "yellow")
        # lanelet2's traffic rules allow a lane change exactly across the dashed lines
        for side, bound in (("left", ll.leftBound), ("right", ll.rightBound)):
            neighbour = getattr(loaded.graph, side)(ll)
            assert (neighbour is not None) == (_bound(bound)[1] == "dashed"), (lane, side)
    stop_elements = {re.id: re for ll in lanelets for re in ll.regulatoryElements}
    assert len(stop_elements) == 1
    (stop,) = stop_elements.values()
    assert stop.attributes["subtype"] == "traffic_sign"
    holders = [ll for ll in lanelets if ll.regulatoryElements]
    assert {ll.attributes["direction"] for ll in holders} == {"forward"} and len(holders) == 2
    line = stop.parameters["ref_line"][0]
    assert line.attributes["type"] == "stop_line"
    for ll in holders:  # the forward lanelets end at the stop line
        end = ll.centerline[len(ll.centerline) - 1]
        assert geometry.distance(line, end) < 0.5


def test_bad_input_is_refused_and_changes_nothing(drive: dict[str, str],
                                                  tmp_path: Path) -> None:
    before = stored("lane-road")
    assert "no raster layer 'nope'" in refused("ingest", "lanes", "--layer", "nope",
                                               "--network", "lane-road")
    assert "network 'nope' does not exist" in refused("ingest", "lanes", "--layer",
                                                      "lane-drive", "--network", "nope")
    east, north = utm_origin()
    coarse = write_tif(tmp_path / "coarse.tif", np.full((3, 50, 50), 90, np.uint8), UTM33,
                       from_origin(round(east), round(north), 0.3, 0.3))
    run("ingest", "raster", str(coarse), "--layer", "lanes-coarse")
    said = refused("ingest", "lanes", "--layer", "lanes-coarse", "--network", "lane-road")
    assert "layer 'lanes-coarse': imagery at 0.3" in said  # as stored: 0.397 m (zoom 18)
    assert "m/px is too coarse for lane markings" in said
    fine = write_tif(tmp_path / "fine.tif", np.full((3, 50, 50), 90, np.uint8), UTM33,
                     from_origin(round(east), round(north), 0.1, 0.1))
    run("ingest", "raster", str(fine), "--layer", "lanes-elsewhere")
    assert "network 'lane-road' has no road over layer 'lanes-elsewhere'" in refused(
        "ingest", "lanes", "--layer", "lanes-elsewhere", "--network", "lane-road")
    assert stored("lane-road") == before


def test_queued_for_a_worker_it_does_the_same(drive: dict[str, str]) -> None:
    before = stored("lane-road")
    said = run("ingest", "lanes", "--layer", "lane-drive", "--network", "lane-road", "--queue")
    job_id = int(said.split()[2])
    tasks.run_job(job_id)
    with session_scope() as session:
        row = session.execute(text("SELECT kind, status, progress, message FROM ingest_jobs "
                                   "WHERE id = :id"), {"id": job_id}).one()
    assert tuple(row)[:3] == ("ingest-lanes", "succeeded", 1.0)
    assert "lanes from the paint of layer lane-drive on 1 of 1 segments" in row.message
    after = stored("lane-road")
    assert [tuple(r)[1:] for r in after[0]] == [tuple(r)[1:] for r in before[0]]  # new ids
    assert after[1] == before[1]


def test_a_lane_that_opens_is_a_range_of_its_own() -> None:
    """A straight road, 1+1 lanes, a right-turn lane opening 40 m along it (its own line
    from there on): two ranges, the second with two lanes forward, and the new line a
    boundary of the second range only."""
    def line(offset: float, start: float = 0.0, kind: str = "solid") -> Paint:
        return Paint(shapely.LineString([(start, offset), (80.0, offset)]), kind, "white",
                     0.15, 0.9)

    paint = [line(-3.2, kind="road_edge"), line(0.0), line(3.2, kind="road_edge"),
             line(-6.2, 40.0, "road_edge")]
    reference = shapely.LineString([(0.0, 0.0), (80.0, 0.0)])
    first, second = lane_ranges(reference, paint)
    assert (first.forward, first.backward, second.forward, second.backward) == (1, 1, 2, 1)
    assert abs(first.station_to_m - 40.0) < 1.0 and second.station_to_m == 80.0
    assert np.allclose(second.widths, [3.0, 3.2, 3.2], atol=0.01)
    rows = boundaries(reference, paint, [first, second])
    new = [r for r in rows if r.source == "paint" and r.offset_m < -5]
    assert len(new) == 1 and new[0].position == 0 and new[0].station_from_m > 39
    guessed = [r for r in rows if r.source == "offset"]
    assert guessed == []  # every boundary of both ranges is painted


def _edge(*points: tuple[float, float], kind: str = "road_edge") -> Paint:
    return Paint(shapely.LineString(points), kind, "white", 0.15, 0.9)


@pytest.mark.parametrize("lane_line_from", [60.0, 40.0])
def test_a_lane_that_opens_along_a_taper_starts_where_the_taper_does(lane_line_from: float
                                                                     ) -> None:
    """1+1 lanes; 40 m along, the right edge runs out by 3 m over 20 m into a turning lane
    whose line is painted from the end of the taper (or from its start): the new range
    starts at the taper's start, not where the line does (or 2 m on), and the taper is
    the new lane's painted edge (it was an ``offset`` guess at the full offset)."""
    reference = shapely.LineString([(0.0, 0.0), (80.0, 0.0)])
    paint = [_edge((0, -3.2), (40, -3.2), (60, -6.2), (80, -6.2)),
             _edge((0, 0), (80, 0), kind="solid"), _edge((0, 3.2), (80, 3.2)),
             _edge((lane_line_from, -3.2), (80, -3.2), kind="dashed")]
    first, second = lane_ranges(reference, paint)
    assert (first.forward, second.forward) == (1, 2)
    assert first.station_to_m == pytest.approx(40.0, abs=0.3)
    edge = [r for r in boundaries(reference, paint, [first, second])
            if r.position == 0 and r.station_from_m > 35]
    assert len(edge) == 1 and edge[0].source == "paint"
    assert edge[0].station_from_m == pytest.approx(40.0, abs=0.3)


def test_tapers_of_wobbling_paint_are_found_where_they_start() -> None:
    """Forty seeded tapers as extraction gives them: 5-50 m long, 2.6-4 m wide, on either
    side, opening or ending, the lane line painted from the taper's start or its end, every
    edge point off by up to 4 cm. The lane always starts (ends) within 1.5 m of where its
    taper does. (Taken where the paint first came within 0.25 m of a boundary, with the
    range's median offset as the old boundary, a 33 m taper started 5.8 m late; a 37 m one
    with its lane line after it widened the range before it past 4.5 m, which was then read
    as a line unseen: one range.)"""
    rng = np.random.default_rng(35)
    reference = shapely.LineString([(0.0, 0.0), (120.0, 0.0)])
    along = np.arange(0.0, 120.01, 0.5)
    for _ in range(40):
        start, length, width = rng.uniform(20, 60), rng.uniform(5, 50), rng.uniform(2.6, 4.0)
        side, ending, line_from_end = rng.choice([-1, 1]), rng.random() < 0.5, rng.random() < 0.5
        offset = side * (3.2 + width * np.clip((along - start) / length, 0, 1)) + rng.normal(
            0, rng.uniform(0, 0.04), len(along))
        x = 120.0 - along if ending else along
        lane_line = start + length if line_from_end else start
        tail = (120.0 - lane_line, 0.0) if ending else (lane_line, 120.0)
        paint = [_edge(*zip(x, offset, strict=True)), _edge((0, 0), (120, 0), kind="solid"),
                 _edge((0, -side * 3.2), (120, -side * 3.2)),
                 _edge((tail[0], side * 3.2), (tail[1], side * 3.2), kind="dashed")]
        first, second = lane_ranges(reference, paint)
        where = 120.0 - start if ending else start
        assert first.station_to_m == pytest.approx(where, abs=1.5), (start, length, width)
        assert (second if not ending else first).taper is not None


def test_a_long_taper_before_its_lane_line_is_not_a_line_unseen() -> None:
    """A 3.8 m lane opening on the left over 37 m from 20.5 m along, its line painted from
    the taper's end: the range before it is not a lane over 4.5 m wide (a line unseen, merged
    into its neighbour: the whole road read 1+2), it ends where the taper starts."""
    reference = shapely.LineString([(0.0, 0.0), (120.0, 0.0)])
    along = np.arange(0.0, 120.01, 0.5)
    edge = 3.2 + 3.8 * np.clip((along - 20.5) / 37.1, 0, 1)
    paint = [_edge(*zip(along, edge, strict=True)), _edge((0, 0), (120, 0), kind="solid"),
             _edge((0, -3.2), (120, -3.2)), _edge((57.6, 3.2), (120, 3.2), kind="dashed")]
    first, second = lane_ranges(reference, paint)
    assert (first.backward, second.backward) == (1, 2)
    assert first.station_to_m == pytest.approx(20.5, abs=1.0)
    assert first.offsets == pytest.approx((-3.2, 0.0, 3.2), abs=0.05)


def test_a_lane_that_ends_along_a_taper_ends_where_the_taper_does() -> None:
    """The mirror: 2+1 lanes narrowing over 20 m from 20 m along: the lane ends at the
    taper's end (40 m), its edge painted along the taper."""
    reference = shapely.LineString([(0.0, 0.0), (80.0, 0.0)])
    paint = [_edge((0, -6.2), (20, -6.2), (40, -3.2), (80, -3.2)),
             _edge((0, 0), (80, 0), kind="solid"), _edge((0, 3.2), (80, 3.2)),
             _edge((0, -3.2), (20, -3.2), kind="dashed")]
    first, second = lane_ranges(reference, paint)
    assert (first.forward, second.forward) == (2, 1)
    assert first.station_to_m == pytest.approx(40.0, abs=0.3)
    edge = [r for r in boundaries(reference, paint, [first, second])
            if r.position == 0 and r.station_to_m < 45]
    assert len(edge) == 1 and edge[0].source == "paint" and edge[0].station_to_m > 39


def test_served_as_a_collection_and_in_the_vector_tiles(client, drive: dict[str, str]) -> None:
    ids = {c["id"] for c in client.get("/collections").json()["collections"]}
    assert "lane-road-lanes" in ids
    page = client.get("/collections/lane-road-lanes/items", params={"kind": "dashed"}).json()
    assert page["numberMatched"] >= 2
    for f in page["features"]:
        p = f["properties"]
        assert f["geometry"]["type"] == "LineString" and p["kind"] == "dashed"
        assert (p["lanes_forward"], p["lanes_backward"]) == (2, 2)
        assert np.allclose([float(w) for w in p["lane_widths_m"].split(",")],
                           [3.5, 3.0, 3.25, 3.75], atol=0.15)
    schema = client.get("/collections/lane-road-lanes/schema").json()
    assert schema["properties"]["kind"]["enum"][:2] == ["solid", "dashed"]
    tj = client.get("/networks/lane-road/tilejson.json").json()
    fields = next(layer["fields"] for layer in tj["vector_layers"] if layer["id"] == "lanes")
    lon, lat = centreline(10.0, 10.0)[0]
    tile = morecantile.tms.get("WebMercatorQuad").tile(lon, lat, 18)
    body = client.get(f"/networks/lane-road/tiles/18/{tile.x}/{tile.y}.mvt").content
    lanes = mapbox_vector_tile.decode(body)["lanes"]["features"]
    assert {f["properties"]["kind"] for f in lanes} >= {"solid", "dashed", "road_edge"}
    assert {k for f in lanes for k in f["properties"]} == set(fields)


def test_edited_like_segments_and_the_lanelet2_map_follows(client, drive: dict[str, str]
                                                         ) -> None:
    """A reviewer makes the right lane line solid (PATCH with If-Match, editor): the stale
    version and an anonymous edit are refused, the history keeps it, and the next Lanelet2
    map forbids changing between the forward lanes along it."""
    line = next(f for f in client.get("/collections/lane-road-lanes/items",
                                      params={"position": 1, "source": "paint"}
                                      ).json()["features"])
    url = f"/collections/lane-road-lanes/items/{line['id']}"
    version = line["properties"]["version"]
    assert client.patch(url, json={"kind": "solid"}).status_code == 401
    stale = client.patch(url, json={"kind": "solid"}, headers={
        **bearer("editor"), "If-Match": f'"{version + 1}"'})
    assert stale.status_code == 412
    bad = client.patch(url, json={"kind": "zigzag"}, headers=bearer("editor"))
    assert bad.status_code == 422 and "kind" in bad.json()["errors"]
    done = client.patch(url, json={"kind": "solid"}, headers={
        **bearer("editor"), "If-Match": f'"{version}"'})
    assert done.status_code == 200, done.text
    assert done.json()["properties"]["kind"] == "solid"
    assert done.headers["ETag"] == f'"{version + 1}"'
    edits = client.get(url + "/history").json()["edits"]
    assert [(e["old"], e["new"]) for e in edits] == [({"kind": "dashed"}, {"kind": "solid"})]
    assert client.post("/collections/lane-road-lanes/items", headers=bearer("editor"),
                       json=line).status_code == 405
    again = run("ingest", "lanes", "--layer", "lane-drive", "--network", "lane-road")
    assert "1 segments keep the lanes a person edited" in again  # never overwritten
    kept = client.get(url).json()
    assert kept["properties"]["kind"] == "solid" and kept["properties"]["version"] == version + 1
    loaded = _exported(drive)
    along = [ll for ll in loaded.lanelets() if ll.attributes["direction"] == "forward"
             and _bound(ll.leftBound if ll.attributes["lane"] == "1" else ll.rightBound)[1]
             == "solid" and geometry.length2d(ll) > 5]
    assert along and all(loaded.graph.left(ll) is None and loaded.graph.right(ll) is None
                         for ll in along)


def _store_lanes(network: str, ranges: list[tuple[float, float, int, int, list[float]]],
                 lines: list[tuple[float, float, float | list[tuple[float, float]],
                                   int | None, str]]) -> None:
    """Stored lanes of the network's one east-going segment at 48 N: ``ranges`` (from, to,
    forward, backward, offsets right to left) and boundary ``lines`` (from, to, offset
    metres north of the centreline or (station, offset) points it runs through, position,
    kind) as ``ingest lanes`` would write them."""
    with session_scope() as session:
        seg, lon0, lat0 = session.execute(text(
            "SELECT s.id, ST_X(ST_StartPoint(s.geom)), ST_Y(ST_StartPoint(s.geom))"
            " FROM road_segments s JOIN networks n ON n.id = s.network_id WHERE n.name = :n"),
            {"n": network}).one()
    east = 1 / (111_320 * np.cos(np.radians(lat0)))
    rows = []
    for lo, hi, offset, position, kind in lines:
        along = np.linspace(lo, hi, 61)
        across = np.interp(along, *np.array(offset).T) if isinstance(offset, list) else \
            np.full(len(along), offset)
        wkt = "LINESTRING(" + ", ".join(f"{lon0 + x * east} {lat0 + o / 111_320}"
                                          for x, o in zip(along, across, strict=True)) + ")"
        rows.append((wkt, kind, position, float(np.median(across)), lo, hi))
    store_lanes(network, seg, ranges, rows)


def _straight_road(tmp_path: Path, name: str, lat: float) -> None:
    road = tmp_path / f"{name}.geojson"
    road.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"lanes_forward": 1, "lanes_backward": 1},
        "geometry": {"type": "LineString", "coordinates": [
            [16.0, lat], [16.0 + 100 / (111_320 * np.cos(np.radians(lat))), lat]]}}]}))
    run("ingest", "network", str(road), "--network", name)


def test_a_lane_line_solid_on_part_of_the_road_forbids_the_change_there(
        database_url: str, tmp_path: Path) -> None:
    """A one-way road of a 3.0 and a 3.5 m lane whose lane line is dashed for 60 m, then
    solid: two lanelets per lane (as wide as painted), the change allowed along the first,
    not the second."""
    _straight_road(tmp_path, "solid-part", 48.2)
    with session_scope() as session:
        session.execute(text("UPDATE road_segments SET oneway = 'forward', lanes_backward = 0 "
                             "WHERE network_id = (SELECT id FROM networks WHERE name = "
                             "'solid-part')"))
    _store_lanes("solid-part", [(0, 100, 2, 0, [-3.5, -0.5, 3.0])],
                 [(0, 100, -3.5, 0, "road_edge"), (0, 60, -0.5, 1, "dashed"),
                  (60, 100, -0.5, 1, "solid"), (0, 100, 3.0, 2, "road_edge")])
    _, loaded = export("solid-part", tmp_path / "solid-part.osm")
    lanelets = sorted(loaded.lanelets(), key=lambda ll: geometry.distance(
        ll.centerline[0], loaded.lanelets()[0].centerline[0]))
    assert len(lanelets) == 4
    for ll in lanelets:
        a = ll.attributes
        width = _width(ll)
        assert abs(width - (3.0 if a["lane"] == "1" else 3.5)) <= 0.02, width
        inner = ll.leftBound if a["lane"] == "1" else ll.rightBound
        side = "left" if a["lane"] == "1" else "right"
        neighbour = getattr(loaded.graph, side)(ll)
        assert (neighbour is not None) == (_bound(inner)[1] == "dashed")
    kinds = sorted((round(geometry.length2d(ll)), _bound(
        ll.leftBound if ll.attributes["lane"] == "1" else ll.rightBound)[1])
        for ll in lanelets)
    assert kinds == [(40, "solid"), (40, "solid"), (60, "dashed"), (60, "dashed")], kinds


def _width_at(ll, fraction: float) -> float:
    """A lanelet's width across its centreline ``fraction`` of the way along it."""
    p = geometry.interpolatedPointAtDistance(geometry.to2D(ll.centerline),
                                             fraction * geometry.length2d(ll))
    return float(geometry.distance(geometry.to2D(ll.leftBound), p)
                 + geometry.distance(geometry.to2D(ll.rightBound), p))


def _opening_map(tmp_path: Path, name: str, lat: float, at: float,
                 edge: float | list[tuple[float, float]]) -> tuple[LoadedMap, Any, Any, Any]:
    """A 1+1 road of 3 m lanes with a turning lane opening on the right ``at`` metres along
    (its edge ``edge``: an offset, or the points it runs through), exported: (the map, the
    first forward lanelet, the lane that carries on, the lane that opens), with no junction
    lanelet (each has a direction)."""
    _straight_road(tmp_path, name, lat)
    _store_lanes(name, [(0, at, 1, 1, [-3.0, 0.0, 3.0]),
                        (at, 100, 2, 1, [-6.0, -3.0, 0.0, 3.0])],
                 [(0, at, -3.0, 0, "road_edge"), (0, at, 0.0, 1, "solid"),
                  (0, at, 3.0, 2, "road_edge"), (at, 100, edge, 0, "road_edge"),
                  (at, 100, -3.0, 1, "dashed"), (at, 100, 0.0, 2, "solid"),
                  (at, 100, 3.0, 3, "road_edge")])
    _, loaded = export(name, tmp_path / f"{name}.osm")
    assert all("direction" in ll.attributes for ll in loaded.lanelets())  # no junction
    forward = [ll for ll in loaded.lanelets() if ll.attributes["direction"] == "forward"]
    first = min(forward, key=lambda ll: ll.centerline[0].x)
    after = {ll.attributes["lane"]: ll for ll in forward if ll.id != first.id}
    assert sorted(after) == ["1", "2"]
    return loaded, first, after["2"], after["1"]


def test_a_lane_that_opens_in_the_lanelet2_map(database_url: str, tmp_path: Path) -> None:
    """1+1 lanes for 50 m, then a second forward lane on the right (a turning lane): the
    forward lanelet is followed by the lane that carries on, with no junction between (the
    bounds carry on), and the new lane opens beside it from a point, 3 m wide 5 m on, reached
    by a lane change across the dashed line; the lane back carries on too."""
    loaded, first, carries_on, opens = _opening_map(tmp_path, "opening", 48.3, 50.0, -6.0)
    assert [ll.id for ll in loaded.graph.following(first)] == [carries_on.id]
    assert loaded.graph.right(carries_on).id == opens.id  # a lane change to the new lane
    assert loaded.graph.getRoute(first, opens) is not None
    assert _width(carries_on) == pytest.approx(3.0, abs=0.05)
    assert _width_at(opens, 0.0) == pytest.approx(0.0, abs=0.05)
    for fraction in (0.2, 0.5, 0.95):  # 3 m wide from 5 m on, as painted
        assert _width_at(opens, fraction) == pytest.approx(3.0, abs=0.05), fraction
    backward = [ll for ll in loaded.lanelets() if ll.attributes["direction"] == "backward"]
    arriving = min(backward, key=lambda ll: abs(ll.centerline[-1].x - opens.centerline[0].x))
    assert len(backward) == 2 and [ll.id for ll in loaded.graph.following(arriving)] == [
        ll.id for ll in backward if ll.id != arriving.id]


def test_a_lane_that_opens_along_a_painted_taper_widens_as_painted(database_url: str,
                                                                   tmp_path: Path) -> None:
    """1+1 lanes for 40 m, then a turning lane on the right whose road edge runs out from
    3 m to 6 m over 20 m: the new lanelet starts at the taper's start and is as wide as the
    paint all along it (1.5 m halfway, 3 m at its end), not 3 m wide 5 m on."""
    loaded, first, carries_on, opens = _opening_map(
        tmp_path, "tapered", 48.32, 40.0, [(40.0, -3.0), (60.0, -6.0), (100.0, -6.0)])
    assert [ll.id for ll in loaded.graph.following(first)] == [carries_on.id]
    assert loaded.graph.right(carries_on).id == opens.id
    assert geometry.length2d(first) == pytest.approx(40.0, abs=0.5)
    assert geometry.length2d(opens) == pytest.approx(60.0, abs=0.5)
    for metres, width in ((0.0, 0.0), (5.0, 0.75), (10.0, 1.5), (20.0, 3.0), (40.0, 3.0)):
        assert _width_at(opens, metres / 60.0) == pytest.approx(width, abs=0.1), metres


def test_a_lane_that_ends_along_a_painted_taper_narrows_as_painted(database_url: str,
                                                                   tmp_path: Path) -> None:
    """2+1 lanes whose right edge runs in from 6 m to 3 m between 40 and 60 m, then 1+1: the
    lane that ends narrows with the paint (1.5 m at 50 m) to a point at 60 m, and the lane
    beside it carries on."""
    _straight_road(tmp_path, "tapered-end", 48.33)
    _store_lanes("tapered-end", [(0, 60, 2, 1, [-6.0, -3.0, 0.0, 3.0]),
                                 (60, 100, 1, 1, [-3.0, 0.0, 3.0])],
                 [(0, 60, [(0.0, -6.0), (40.0, -6.0), (60.0, -3.0)], 0, "road_edge"),
                  (0, 60, -3.0, 1, "dashed"), (0, 60, 0.0, 2, "solid"),
                  (0, 60, 3.0, 3, "road_edge"), (60, 100, -3.0, 0, "road_edge"),
                  (60, 100, 0.0, 1, "solid"), (60, 100, 3.0, 2, "road_edge")])
    _, loaded = export("tapered-end", tmp_path / "tapered-end.osm")
    assert all("direction" in ll.attributes for ll in loaded.lanelets())  # no junction
    forward = [ll for ll in loaded.lanelets() if ll.attributes["direction"] == "forward"]
    last = max(forward, key=lambda ll: ll.centerline[-1].x)
    ends = next(ll for ll in forward if ll.attributes["lane"] == "1" and ll.id != last.id)
    assert list(loaded.graph.following(ends)) == []
    assert geometry.length2d(ends) == pytest.approx(60.0, abs=0.5)
    for metres, width in ((30.0, 3.0), (40.0, 3.0), (50.0, 1.5), (55.0, 0.75), (60.0, 0.0)):
        assert _width_at(ends, metres / 60.0) == pytest.approx(width, abs=0.1), metres


def _tapered_orthophoto(path: Path) -> tuple[float, float]:
    """A 0.05 m/px orthophoto (UTM 33N) of a straight east-going 1+1 road, 3 m lanes, whose
    right edge runs out to 6 m over 20 m from 40 m along, a dashed line parting the turning
    lane from 60 m on: white edges, a yellow centre line, grey asphalt on darker ground.
    Returns the (easting, northing) of the road's centre at its start."""
    res, east0, north0 = 0.05, *utm_origin(15.3, 48.25)
    east0, north0 = round(east0), round(north0)
    x = np.arange(0.0, 110.0, res)[None, :] - 5.0  # metres along the road
    y = 12.0 - np.arange(0.0, 24.0, res)[:, None]  # metres left of it
    right = -3.0 - 3.0 * np.clip((x - 40.0) / 20.0, 0.0, 1.0)
    rng = np.random.default_rng(7)
    grey = np.where((y > right - 0.4) & (y < 3.4), 105.0, 62.0)
    grey = grey + rng.normal(0, 6, grey.shape)
    rgb = np.repeat(grey[None], 3, axis=0)

    def paint(on: np.ndarray, colour: tuple[int, int, int]) -> None:
        for band, value in enumerate(colour):
            rgb[band][on] = value

    half = 0.075
    inside = (x >= 0) & (x <= 100)
    paint(inside & (np.abs(y - right) < half), (235, 235, 235))
    paint(inside & (np.abs(y - 3.0) < half), (235, 235, 235))
    paint(inside & (np.abs(y) < half), (225, 190, 40))
    paint((x >= 60) & (x <= 100) & ((x - 60) % 9.0 < 3.0) & (np.abs(y + 3.0) < half),
          (235, 235, 235))
    write_tif(path, rgb.clip(0, 255).astype(np.uint8), UTM33,
              from_origin(east0 - 5.0, north0 + 12.0, res, res))
    return float(east0), float(north0)


def test_a_painted_taper_from_the_imagery_to_the_lanelet2_map(database_url: str,
                                                             tmp_path: Path) -> None:
    """The taper of a turning lane read from an orthophoto: ``ingest lanes`` starts the
    lane where the edge starts to run out, and the map's new lanelet widens with the paint
    (half its width halfway along the taper), not to its full width 5 m after the line."""
    east, north = _tapered_orthophoto(tmp_path / "taper.tif")
    run("ingest", "raster", str(tmp_path / "taper.tif"), "--layer", "taper-ortho")
    lonlat = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)
    road = tmp_path / "taper-road.geojson"
    road.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"lanes_forward": 1, "lanes_backward": 1},
        "geometry": {"type": "LineString", "coordinates": [
            list(lonlat.transform(east + m, north)) for m in (2.0, 98.0)]}}]}))
    run("ingest", "network", str(road), "--network", "taper-road")
    said = run("ingest", "lanes", "--layer", "taper-ortho", "--network", "taper-road")
    assert "2 lane ranges (1+1, 2+1 lanes forward+backward, 1 opening or ending along a " \
        "painted taper)" in said, said
    ranges, _ = stored("taper-road")
    assert [(r.lanes_forward, r.lanes_backward) for r in ranges] == [(1, 1), (2, 1)]
    assert ranges[0].station_to_m == pytest.approx(38.0, abs=1.0)  # 40 m from x = 2 m
    _, loaded = export("taper-road", tmp_path / "taper.osm")
    assert all("direction" in ll.attributes for ll in loaded.lanelets())  # no junction
    forward = [ll for ll in loaded.lanelets() if ll.attributes["direction"] == "forward"]
    opens = next(ll for ll in forward if ll.attributes["lane"] == "1"
                 and geometry.length2d(ll) > 50)
    length = geometry.length2d(opens)
    for metres, width in ((10.0, 1.5), (30.0, 3.0)):
        assert _width_at(opens, metres / length) == pytest.approx(width, abs=0.2), metres


def test_the_synthetic_drive_s_turning_lane_opens_along_its_taper(database_url: str,
                                                                 tmp_path: Path) -> None:
    """The synthetic drive (16 frames) with a turning lane opening 10 m along the vehicle's
    path (the right edge running out by 3 m over 8 m, a dashed line beyond it), through
    ``ingest ipm``, ``ingest lanes`` on the road's true centre and the Lanelet2 export: 2+2
    lanes, then 3+2 from where the taper starts (16 m along the segment, within 1 m), and the
    new lanelet widens with the paint (within 0.25 m at 1, 2, 4, 6 and 12 m into it)."""
    drive = Drive.in_lane(replace(PAINT, stop_at_m=None, turn_at_m=10.0, turn_taper_m=8.0), 1)
    said = ingest_drive(tmp_path, drive, 16, "turn", 30.0, 2)
    assert "1 opening or ending along a painted taper" in said, said
    ranges, _ = stored("turn-road")
    assert [(r.lanes_forward, r.lanes_backward) for r in ranges] == [(2, 2), (3, 2)]
    assert ranges[0].station_to_m == pytest.approx(16.0, abs=1.0)
    _, loaded = export("turn-road", tmp_path / "turn.osm")
    opens = next(ll for ll in loaded.lanelets() if ll.attributes["direction"] == "forward"
                 and ll.attributes["lane"] == "1" and _width_at(ll, 1.0) > 2.0)
    assert _width_at(opens, 0.0) < 0.3
    assert drive.lanes is not None
    for metres in (1.0, 2.0, 4.0, 6.0, 12.0):  # the lanelet and the path are concentric arcs
        painted = float(drive.lanes.turn_out_m(10.0 + metres))
        assert _width_at(opens, metres / 20.0) == pytest.approx(painted, abs=0.25), metres


def test_a_lane_that_ends_in_the_lanelet2_map(database_url: str, tmp_path: Path) -> None:
    """2+1 lanes for 50 m, then 1+1: the right forward lane narrows to a point where it ends
    (no lanelet follows it: a vehicle in it changes lanes across the dashed line), the other
    carries on into the one forward lane."""
    _straight_road(tmp_path, "ending", 48.35)
    _store_lanes("ending", [(0, 50, 2, 1, [-6.0, -3.0, 0.0, 3.0]),
                            (50, 100, 1, 1, [-3.0, 0.0, 3.0])],
                 [(0, 50, -6.0, 0, "road_edge"), (0, 50, -3.0, 1, "dashed"),
                  (0, 50, 0.0, 2, "solid"), (0, 50, 3.0, 3, "road_edge"),
                  (50, 100, -3.0, 0, "road_edge"), (50, 100, 0.0, 1, "solid"),
                  (50, 100, 3.0, 2, "road_edge")])
    _, loaded = export("ending", tmp_path / "ending.osm")
    assert all("direction" in ll.attributes for ll in loaded.lanelets())  # no junction
    forward = [ll for ll in loaded.lanelets() if ll.attributes["direction"] == "forward"]
    last = max(forward, key=lambda ll: ll.centerline[-1].x)
    before = {ll.attributes["lane"]: ll for ll in forward if ll.id != last.id}
    assert sorted(before) == ["1", "2"]
    ends, carries_on = before["1"], before["2"]
    assert list(loaded.graph.following(ends)) == []
    assert [ll.id for ll in loaded.graph.following(carries_on)] == [last.id]
    assert loaded.graph.left(ends).id == carries_on.id
    assert loaded.graph.getRoute(ends, last) is not None
    assert _width_at(ends, 1.0) == pytest.approx(0.0, abs=0.05)
    assert _width_at(ends, 0.5) == pytest.approx(3.0, abs=0.05)


def test_paint_that_breaks_the_one_way_rule_is_not_mapped(database_url: str,
                                                          tmp_path: Path) -> None:
    """A two-way road whose line between the directions went unseen reads as 2+0 lanes:
    the map draws it as a road without paint (1+1, guessed bounds), not with no lane back."""
    _straight_road(tmp_path, "unseen-centre", 48.4)
    _store_lanes("unseen-centre", [(0, 100, 2, 0, [-3.0, 0.0, 3.0])],
                 [(0, 100, -3.0, 0, "road_edge"), (0, 100, 0.0, 1, "dashed"),
                  (0, 100, 3.0, 2, "road_edge")])
    _, loaded = export("unseen-centre", tmp_path / "unseen-centre.osm")
    directions = sorted(ll.attributes["direction"] for ll in loaded.lanelets())
    assert directions == ["backward", "forward"]
    assert all(_bound(b)[2] == "" for ll in loaded.lanelets()
               for b in (ll.leftBound, ll.rightBound))  # no painted colour: not the paint


def test_a_stop_line_before_a_traffic_light_is_not_a_stop_sign(database_url: str,
                                                                tmp_path: Path) -> None:
    """A painted stop line 90 m along a road whose end node has a traffic light: the lanes
    are governed by the light's element alone (a stop sign too would stop on green); the
    painted line is still in the map. Without the light it is a stop sign."""
    for name, lat, light in (("stop-light", 48.5, True), ("stop-sign", 48.6, False)):
        _straight_road(tmp_path, name, lat)
        with session_scope() as session:
            session.execute(text(
                "UPDATE road_nodes SET traffic_light = :light WHERE id = (SELECT s.target_node "
                "FROM road_segments s JOIN networks n ON n.id = s.network_id "
                "WHERE n.name = :n)"), {"light": light, "n": name})
        _store_lanes(name, [(0, 100, 1, 1, [-3.0, 0.0, 3.0])],
                     [(0, 100, -3.0, 0, "road_edge"), (0, 100, 0.0, 1, "solid"),
                      (0, 100, 3.0, 2, "road_edge"), (89.9, 90.1, -1.5, None, "stop_line")])
        with session_scope() as session:  # a stop line lies across the lanes, not along
            session.execute(text(
                "UPDATE lane_boundaries SET geom = ST_MakeLine(ST_Project(ST_StartPoint(geom)"
                "::geography, 1.5, radians(180))::geometry, ST_Project(ST_StartPoint(geom)"
                "::geography, 1.5, 0)::geometry) WHERE kind = 'stop_line' AND network_id = "
                "(SELECT id FROM networks WHERE name = :n)"), {"n": name})
        _, loaded = export(name, tmp_path / f"{name}.osm")
        kinds = sorted(re.attributes["subtype"] for re in loaded.map.regulatoryElementLayer)
        assert kinds == (["traffic_light"] if light else ["traffic_sign"]), (name, kinds)
        lines = [ls for ls in loaded.map.lineStringLayer
                 if ls.attributes["type"] == "stop_line" and "ugvmap:source" in ls.attributes]
        assert len(lines) == 1, name


def test_a_painted_crossing_is_kept_whole_and_mapped_as_a_crosswalk_lanelet(
        database_url: str, tmp_path: Path) -> None:
    """A zebra crossing 50 m along a 1+1 road (6 m across, 3 m along it): ``ingest lanes``
    keeps it whole without a position, and the Lanelet2 map has a ``crosswalk`` lanelet
    (``zebra_marking`` bounds 3 m apart) across both lanes, for pedestrians and not cars."""
    paint = [Paint(shapely.LineString([(0.0, o), (100.0, o)]), k, "white", 0.15, 0.9)
             for o, k in ((-3.0, "road_edge"), (0.0, "solid"), (3.0, "road_edge"))]
    zebra = Paint(shapely.LineString([(50.0, -3.0), (50.0, 3.0)]), "crosswalk", "white", 3.0,
                  0.8)
    reference = shapely.LineString([(0.0, 0.0), (100.0, 0.0)])
    ranges = lane_ranges(reference, [*paint, zebra])
    assert [(r.forward, r.backward) for r in ranges] == [(1, 1)]
    (crossing,) = [r for r in boundaries(reference, [*paint, zebra], ranges)
                   if r.kind == "crosswalk"]
    assert crossing.position is None and crossing.width_m == 3.0
    assert (crossing.station_from_m, crossing.station_to_m) == pytest.approx((50, 50), abs=0.3)

    _straight_road(tmp_path, "zebra", 48.8)
    _store_lanes("zebra", [(0, 100, 1, 1, [-3.0, 0.0, 3.0])],
                 [(0, 100, -3.0, 0, "road_edge"), (0, 100, 0.0, 1, "solid"),
                  (0, 100, 3.0, 2, "road_edge")])
    with session_scope() as session:
        session.execute(text(
            "INSERT INTO lane_boundaries (network_id, segment_id, geom, kind, colour, width_m, "
            "confidence, position, offset_m, station_from_m, station_to_m) SELECT network_id, "
            "segment_id, ST_MakeLine(ST_Project(p::geography, 3.0, radians(180))::geometry, "
            "ST_Project(p::geography, 3.0, 0)::geometry), 'crosswalk', 'white', 3.0, 0.8, NULL, "
            "0.0, 50.0, 50.0 FROM (SELECT network_id, segment_id, "
            "ST_LineInterpolatePoint(geom, 0.5) AS p FROM lane_boundaries WHERE kind = 'solid' "
            "AND network_id = (SELECT id FROM networks WHERE name = 'zebra')) AS mid"))
    result, loaded = export("zebra", tmp_path / "zebra.osm")
    assert result.summary.from_paint == {"crosswalks": 1}
    (walk,) = [ll for ll in loaded.lanelets() if ll.attributes["subtype"] == "crosswalk"]
    assert {_bound(b)[0] for b in (walk.leftBound, walk.rightBound)} == {"zebra_marking"}
    assert _width(walk) == pytest.approx(3.0, abs=0.05)
    assert geometry.length2d(walk) == pytest.approx(6.0, abs=0.1)
    roads = [ll for ll in loaded.lanelets() if ll.attributes["subtype"] == "road"]
    assert len(roads) == 2 and all(geometry.overlaps2d(walk, ll) for ll in roads)
    walking = traffic_rules.create(traffic_rules.Locations.Germany,
                                   traffic_rules.Participants.Pedestrian)
    assert walking.canPass(walk) and not loaded.rules.canPass(walk)
