"""Visiting-order optimisation, isochrones, dense waypoints and the ``ugvmap route`` CLI."""

from __future__ import annotations

import itertools
import math

import numpy as np
import psycopg
import pytest
from click.testing import CliRunner

from app.routing.optimize import held_karp, nearest_neighbour_2opt, path_cost
from cli.main import main
from testkit import synthetic
from tests.routing_support import dsn, route, unique, xy


def brute_force(cost: np.ndarray) -> float:
    n = len(cost)
    return min(path_cost(cost, [0, *p, n - 1]) for p in itertools.permutations(range(1, n - 1)))


@pytest.mark.parametrize("seed", range(5))
def test_held_karp_is_optimal_on_asymmetric_costs(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cost = rng.uniform(1, 100, (8, 8))
    order = held_karp(cost)
    assert sorted(order) == list(range(8)) and order[0] == 0 and order[-1] == 7
    assert path_cost(cost, order) == pytest.approx(brute_force(cost))


def test_two_opt_heuristic_is_a_valid_good_path() -> None:
    rng = np.random.default_rng(1)
    pts = rng.uniform(0, 1000, (40, 2))
    cost = np.hypot(*(pts[:, None, :] - pts[None, :, :]).transpose(2, 0, 1))
    order = nearest_neighbour_2opt(cost)
    assert sorted(order) == list(range(40)) and order[0] == 0 and order[-1] == 39
    assert path_cost(cost, order) < path_cost(cost, list(range(40))) / 3


@pytest.fixture(scope="module")
def street(database_url: str) -> dict:
    """A straight 1 km two-way street at 36 km/h (10 m/s) in five 200 m segments, plus a
    1 km one-way street 500 m north of it."""
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        name = unique("street")
        net = synthetic.create_network(conn, name)
        for x in range(0, 1000, 200):
            synthetic.add_line(conn, net, [xy(x, 0), xy(x + 200, 0)], speed_limit_kph=36)
        synthetic.add_line(conn, net, [xy(0, 500), xy(1000, 500)], speed_limit_kph=36,
                           oneway="forward")
    return {"name": name}


def test_optimize_orders_task_points(client, street) -> None:
    pts = [xy(0, -5), xy(700, -5), xy(200, -5), xy(500, -5), xy(1000, -5)]
    plain = route(client, street["name"], pts, cost="distance")
    best = route(client, street["name"], pts, cost="distance", optimize="true")
    assert plain["routes"][0]["distance"] == pytest.approx(2000, abs=1)
    assert best["routes"][0]["distance"] == pytest.approx(1000, abs=1)
    assert [w["waypoint_index"] for w in best["waypoints"]] == [0, 3, 1, 2, 4]


def _reached_m(body: dict) -> float:
    total = 0.0
    for f in body["features"]:
        c = f["geometry"]["coordinates"]
        total += sum(math.dist(a, b) for a, b in itertools.pairwise(c)) * 111_320 * math.cos(
            math.radians(42.5))
    return total


@pytest.mark.parametrize(("params", "reach"), [({"seconds": 20}, 400.0), ({"meters": 150}, 300.0)])
def test_isochrone_on_two_way_street(client, street, params, reach) -> None:
    lon, lat = xy(500, -3)
    r = client.get(f"/networks/{street['name']}/isochrone",
                   params={"point": f"{lon},{lat}", **params})
    assert r.status_code == 200, r.text
    assert _reached_m(r.json()) == pytest.approx(reach, rel=0.01)


def test_isochrone_on_one_way_street_goes_forward_only(client, street) -> None:
    lon, lat = xy(500, 503)
    body = client.get(f"/networks/{street['name']}/isochrone",
                      params={"point": f"{lon},{lat}", "seconds": 20}).json()
    assert _reached_m(body) == pytest.approx(200.0, rel=0.01)
    xs = [c[0] for f in body["features"] for c in f["geometry"]["coordinates"]]
    assert min(xs) == pytest.approx(xy(500, 500)[0], abs=1e-6)  # starts at the point


def test_isochrone_needs_one_budget(client, street) -> None:
    r = client.get(f"/networks/{street['name']}/isochrone",
                   params={"point": "1.5,42.5", "seconds": 5, "meters": 5})
    assert r.status_code == 400


def test_dense_waypoints_in_local_metric_frame(client, street) -> None:
    body = route(client, street["name"], [xy(100, -2), xy(350, -2)], format="waypoints",
                 spacing=10)
    pts = body["points"]
    assert body["frame"]["origin"] == pytest.approx(list(xy(100, 0)), abs=1e-7)
    assert len(pts) == 26  # 0, 10, ..., 250 m
    assert (pts[0]["x"], pts[0]["y"]) == pytest.approx((0.0, 0.0), abs=1e-3)
    steps = [math.dist((a["x"], a["y"]), (b["x"], b["y"])) for a, b in itertools.pairwise(pts)]
    assert steps == pytest.approx([10.0] * 25, abs=0.01)
    assert pts[-1]["x"] == pytest.approx(250.0, abs=0.5) and abs(pts[-1]["y"]) < 0.5
    assert {p["speed_limit_kph"] for p in pts} == {36.0}
    assert len({p["segment_id"] for p in pts}) == 2  # crosses from one segment to the next


def test_cli_route_summary_and_errors(street) -> None:
    runner = CliRunner()
    pts = f"{xy(100, -2)[0]},{xy(100, -2)[1]};{xy(600, -2)[0]},{xy(600, -2)[1]}"
    ok = runner.invoke(main, ["route", street["name"], "--points", pts, "--cost", "distance"])
    assert ok.exit_code == 0, ok.output
    assert "total: 500." in ok.output
    missing = runner.invoke(main, ["route", "no-such-net", "--points", pts])
    assert missing.exit_code == 1 and "NotFound" in missing.output
    assert "Traceback" not in missing.output


def test_cli_route_help_says_what_each_option_takes() -> None:
    """``--spacing`` and ``--radius`` read as metres, not TEXT (issue 34); the vehicle is a
    choice of the profiles."""
    out = CliRunner().invoke(main, ["route", "--help"], terminal_width=200).output
    options = {line.split()[0]: line.split()[1] for line in out.splitlines()
               if line.strip().startswith("--") and len(line.split()) > 1}
    assert options["--spacing"] == "METRES" and options["--radius"] == "METRES|unlimited"
    assert options["--points"] == "LON,LAT;LON,LAT[;...]" and options["--avoid"] == "CLASSES"
    assert options["--profile"] == "[car|sidewalk|driving|robot]"
    assert "TEXT" not in out
