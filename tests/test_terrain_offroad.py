"""Off-road routes over a synthetic scene with known answers: a ridge crossed only at a pass,
a forbidden lake, a start too steep to drive, a mission with no road at all, a road joined
where the total time is least (checked by brute force), and ``z`` in the waypoints."""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer
from rasterio.transform import from_origin

from app.db.session import get_engine, session_scope
from app.routing.profiles import CAR
from app.terrain.roads import build_roads
from app.terrain.surface import surface_for
from ingest.network import RoadAttributes, RoadLine, write_network
from ingest.raster.job import ingest_raster
from testkit.raster_synth import UTM33, utm_origin
from testkit.terrain_checks import brute_force_join
from testkit.terrain_synth import disk_mask, ridge_with_pass, write_dem

RES = 5.0
WIDTH, HEIGHT = 300, 240  # 1500 x 1200 m
TO_LONLAT = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)


class Scene:
    """The ridge DEM (and a lake mask) ingested once; places in metres east/south of its
    top-left corner."""

    def __init__(self, tmp: Path) -> None:
        e, n = utm_origin(15.3, 48.4)
        self.transform = from_origin(round(e), round(n), RES, RES)
        self.dem = f"ridge-{uuid.uuid4().hex[:8]}"
        self.lake = f"lake-{uuid.uuid4().hex[:8]}"
        write_dem(tmp / "ridge.tif", ridge_with_pass((self.transform.c, self.transform.f)),
                  UTM33, self.transform, WIDTH, HEIGHT)
        ingest_raster([tmp / "ridge.tif"], self.dem, kind="elevation")
        disk_mask(tmp / "lake.tif", UTM33, self.transform, WIDTH, HEIGHT,
                  self.utm(400, 400), 90.0)
        ingest_raster([tmp / "lake.tif"], self.lake, kind="raster")

    def utm(self, east: float, south: float) -> tuple[float, float]:
        return self.transform.c + east, self.transform.f - south

    def lonlat(self, east: float, south: float) -> tuple[float, float]:
        lon, lat = TO_LONLAT.transform(*self.utm(east, south))
        return float(lon), float(lat)

    def metres(self, lon: float, lat: float) -> tuple[float, float]:
        """East and south of the corner, of a lon/lat."""
        e, n = Transformer.from_crs("EPSG:4326", UTM33, always_xy=True).transform(lon, lat)
        return e - self.transform.c, self.transform.f - n


@pytest.fixture(scope="module")
def scene(database_url: str, tmp_path_factory: pytest.TempPathFactory) -> Scene:
    return Scene(tmp_path_factory.mktemp("scene"))


def network(lines: list[list[tuple[float, float]]], speed: float = 50.0) -> str:
    name = f"net-{uuid.uuid4().hex[:8]}"
    with session_scope() as session:
        write_network(session, name, [RoadLine(c, RoadAttributes(1, 1, speed, road_class="track"))
                                      for c in lines])
    return name


@pytest.fixture(scope="module")
def far_road(scene: Scene) -> str:
    """A network whose only road is 5 km from the scene: no road to join."""
    return network([[scene.lonlat(-5000, 0), scene.lonlat(-5000, 500)]])


def route(client, net: str, scene: Scene, pts: list[tuple[float, float]], **extra: str):
    params = {"points": ";".join(f"{lon:.7f},{lat:.7f}" for lon, lat in pts),
              "offroad": "true", "elevation": scene.dem, **extra}
    return client.get(f"/networks/{net}/route", params=params)


def coords_m(scene: Scene, body: dict) -> np.ndarray:
    return np.array([scene.metres(lon, lat) for lon, lat in
                     body["routes"][0]["geometry"]["coordinates"]])


def test_the_route_takes_the_pass_not_the_cliff_with_no_road_at_all(client, scene,
                                                                     far_road) -> None:
    resp = route(client, far_road, scene, [scene.lonlat(200, 500), scene.lonlat(1300, 500)])
    assert resp.status_code == 200, resp.text
    r = resp.json()["routes"][0]
    assert [p["offroad"] for p in r["parts"]] == [True]  # entirely off road
    leg = r["legs"][0]
    assert leg["offroad"] and [s["mode"] for s in leg["steps"]] == ["offroad"]
    xy = coords_m(scene, resp.json())
    crossing = xy[np.argmin(np.abs(xy[:, 0] - 750))]
    assert abs(crossing[1] - 850) < 60, crossing  # over the pass, 350 m off the straight line
    profile = np.array(leg["steps"][0]["slope_profile"])
    assert profile[-1, 0] == pytest.approx(r["distance"], rel=0.05)
    assert np.abs(profile[1:, 2]).max() < np.tan(np.radians(20)) * 100 * 1.5
    assert r["duration"] > r["distance"] / (20 / 3.6)  # never faster than on the flat


def test_a_forbidden_lake_is_driven_around(client, scene, far_road) -> None:
    pts = [scene.lonlat(250, 400), scene.lonlat(550, 400)]
    straight = route(client, far_road, scene, pts).json()["routes"][0]
    around = route(client, far_road, scene, pts, forbid=scene.lake)
    assert around.status_code == 200, around.text
    xy = coords_m(scene, around.json())
    assert np.hypot(xy[:, 0] - 400, xy[:, 1] - 400).min() > 85
    assert around.json()["routes"][0]["distance"] > straight["distance"] + 60
    inside = route(client, far_road, scene, [scene.lonlat(400, 400), pts[1]], forbid=scene.lake)
    assert inside.status_code == 422
    assert "point 1" in inside.json()["message"] and "forbidden" in inside.json()["message"]


def test_a_start_on_a_slope_too_steep_is_refused_saying_which_point_and_what_slope(
        client, scene, far_road) -> None:
    resp = route(client, far_road, scene, [scene.lonlat(200, 500), scene.lonlat(730, 300)])
    assert resp.status_code == 422
    body = resp.json()
    assert body["code"] == "NoSegment"
    assert "point 2" in body["message"] and "° ; " not in body["message"]
    slope = float(body["message"].split("slope of ")[1].split("°")[0])
    assert 40 < slope < 70 and "at most 20°" in body["message"]


def test_no_path_and_bad_options_are_refused(client, scene, far_road) -> None:
    walled = route(client, far_road, scene, [scene.lonlat(200, 500), scene.lonlat(1300, 500)],
                   max_slope="5")
    assert walled.status_code == 422 and walled.json()["code"] == "NoRoute"
    pts = f"{scene.lonlat(200, 500)[0]},{scene.lonlat(200, 500)[1]};" \
          f"{scene.lonlat(300, 500)[0]},{scene.lonlat(300, 500)[1]}"
    no_layer = client.get(f"/networks/{far_road}/route", params={"points": pts,
                                                                    "offroad": "true"})
    assert no_layer.status_code == 400 and "elevation=SLUG" in no_layer.json()["message"]
    junk = client.get(f"/networks/{far_road}/route", params={"points": pts, "offroad": "true",
                                                              "elevation": "../Etc"})
    assert junk.status_code == 400 and "not a layer slug" in junk.json()["message"]
    missing = route(client, far_road, scene, [scene.lonlat(200, 500), scene.lonlat(300, 500)],
                    elevation="no-such-dem")
    assert missing.status_code == 404 and "no-such-dem" in missing.json()["message"]
    stray = client.get(f"/networks/{far_road}/route", params={"points": pts, "max_slope": "5"})
    assert stray.status_code == 400 and "offroad=true only" in stray.json()["message"]
    osrm = client.get(f"/networks/{far_road}/route/v1/driving/{pts}",
                      params={"offroad": "true"})
    assert osrm.status_code == 400 and "offroad" in osrm.json()["message"]


def test_waypoints_carry_z_and_grade(client, scene, far_road) -> None:
    resp = route(client, far_road, scene, [scene.lonlat(200, 500), scene.lonlat(1300, 500)],
                 format="waypoints", spacing="10")
    assert resp.status_code == 200, resp.text
    points = resp.json()["points"]
    assert len(points) > 100 and all(p["offroad"] for p in points)
    z = np.array([p["z"] for p in points])
    surface = ridge_with_pass((scene.transform.c, scene.transform.f))
    truth = [float(surface(*map(np.array, scene.utm(*scene.metres(p["lon"], p["lat"])))))
             for p in points]
    assert np.abs(z - truth).max() < 1.5  # bilinear on a 5 m grid of a smooth surface
    assert z.max() > 105  # it climbs over the pass
    grades = np.array([p["grade_pct"] for p in points[:-1]])
    assert np.allclose(grades, np.diff(z) / np.diff([p["s"] for p in points]) * 100, atol=0.05)


def test_the_road_is_joined_where_the_total_time_is_least(client, scene) -> None:
    # A fast road north-south west of the ridge, through the pass and on to the east.
    road = [scene.lonlat(x, y) for x, y in
            [(300, 100), (300, 850), (750, 850), (1200, 850), (1200, 100)]]
    net = network([road], speed=80.0)
    a, b = scene.lonlat(150, 150), scene.lonlat(1350, 200)
    resp = route(client, net, scene, [a, b])
    assert resp.status_code == 200, resp.text
    r = resp.json()["routes"][0]
    assert [p["offroad"] for p in r["parts"]] == [True, False, True]
    assert [s["mode"] for s in r["legs"][0]["steps"]] == ["offroad", "driving", "offroad"]
    # Brute force: every pair of road vertices (u, v), off road to u, the road u -> v, off
    # road from v, on the same surface and road graph.
    with get_engine().connect() as conn:
        surface = surface_for(conn, scene.dem, CAR.offroad)
    from app.routing.planner import graph_at
    from app.routing.reads import read_connection
    from app.routing.snap import network_graph

    with read_connection() as reads:
        graph = network_graph(reads, net, graph_at)
    roads = build_roads(graph, surface, frozenset(), 3.6 / CAR.offroad.speeds[0][1])
    ca, cb = surface.grid.cell_of(*a), surface.grid.cell_of(*b)
    assert ca is not None and cb is not None
    assert r["duration"] == pytest.approx(brute_force_join(surface, roads, ca, cb), abs=0.15)


def test_the_command_line_plans_the_same_off_road_route(client, scene, far_road) -> None:
    from click.testing import CliRunner

    from cli.main import main

    a, b = scene.lonlat(200, 500), scene.lonlat(1300, 500)
    pts = f"{a[0]:.7f},{a[1]:.7f};{b[0]:.7f},{b[1]:.7f}"
    out = CliRunner().invoke(main, ["route", far_road, "--points", pts, "--offroad",
                                    "--elevation", scene.dem])
    assert out.exit_code == 0, out.output
    http = route(client, far_road, scene, [a, b]).json()["routes"][0]
    assert f"offroad {http['distance']:.0f} m" in out.output
    steep = CliRunner().invoke(main, ["route", far_road, "--points", pts, "--offroad",
                                      "--elevation", scene.dem, "--max-slope", "5"])
    assert steep.exit_code == 1 and "NoRoute" in steep.output


def test_a_point_on_a_road_over_a_steep_flank_may_start_there(client, scene) -> None:
    """The ground under a road is drivable whatever its slope (a road cut into a flank)."""
    net = network([[scene.lonlat(600, 500), scene.lonlat(900, 500)]])
    on_flank = scene.lonlat(728, 500)  # on the road, where the ground slopes ~50 degrees
    resp = route(client, net, scene, [on_flank, scene.lonlat(200, 150)], radius="1")
    assert resp.status_code == 200, resp.text
    assert [p["offroad"] for p in resp.json()["routes"][0]["parts"]][-1] is True
