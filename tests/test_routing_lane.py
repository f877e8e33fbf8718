"""The routing lane (``app.routing.lane_router``) answers every routing GET exactly as the
FastAPI endpoints behind it do: same status, same headers that matter, same body, for answers
and for every kind of error, on both URL families."""

from __future__ import annotations

from collections.abc import Iterator

import psycopg
import pytest
from fastapi.testclient import TestClient

from app.main import create_app
from app.routing.lane_router import RoutingLane
from tests.routing_support import dsn, town, unique, xy


@pytest.fixture(scope="module")
def town_name(database_url: str) -> str:
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        return town(conn, unique("lane"))["name"]


@pytest.fixture(scope="module")
def clients(database_url: str) -> Iterator[tuple[TestClient, TestClient]]:
    """The app as served (lane first), and the same app without its lane."""
    plain = create_app()
    plain.router.routes[:] = [r for r in plain.router.routes if not isinstance(r, RoutingLane)]
    lane = create_app()
    assert isinstance(lane.router.routes[0], RoutingLane)
    with TestClient(lane) as with_lane, TestClient(plain) as without:
        yield with_lane, without


def _urls(name: str) -> list[str]:
    a, b, c = (f"{x!r},{y!r}" for x, y in (xy(10, 0), xy(390, 0), xy(400, 150)))
    base = f"/networks/{name}"
    return [
        f"{base}/route/v1/driving/{a};{b}",
        f"{base}/route/v1/car/{a};{b};{c}.json?steps=true&annotations=true&overview=full",
        f"{base}/nearest/v1/driving/{a}?number=2",
        f"{base}/table/v1/driving/{a};{b};{c}?annotations=duration,distance",
        f"{base}/trip/v1/driving/{a};{b};{c}",
        f"{base}/match/v1/driving/{a};{b}?timestamps=0;60",
        f"{base}/route?points={a};{b}",
        f"{base}/route?points={a};{b}&steps=false&geometries=polyline6",
        f"{base}/nearest?point={a}",
        f"{base}/table?points={a};{b}",
        # faults: OSRM's codes and statuses on OSRM's URLs, ours on ours
        f"{base}/route/v2/driving/{a};{b}",
        f"{base}/route/v1/dr%20ving/{a};{b}",
        f"{base}/route/v1/driving/{a};{b}.flatbuffers",
        f"{base}/route/v1/driving/{a};nan,1",
        f"{base}/route/v1/driving/{a};{b}?bogus=1",
        f"{base}/route/v1/driving/{a};{b}?steps=true&steps=false",
        f"{base}/route/v1/driving/{a};80,80",
        f"/networks/no-such-network/route/v1/driving/{a};{b}",
        f"/networks/{'x' * 300}/route/v1/driving/{a};{b}",
        f"{base}/route?points={a}",
        f"{base}/route?points={a};80,80",
        f"{base}/route?points={a};{b}&alternatives=yes",
        f"{base}/route",
        f"/networks/no-such-network/route?points={a};{b}",
        f"{base}/tile/v1/driving/tile(1,2,3).mvt",
        f"{base}/route/v1/driving",
    ]


def test_the_lane_answers_as_the_endpoints_do(clients, town_name: str) -> None:
    with_lane, without = clients
    statuses = set()
    for url in _urls(town_name):
        got, expected = with_lane.get(url), without.get(url)
        assert got.status_code == expected.status_code, url
        assert got.headers.get("content-type") == expected.headers.get("content-type"), url
        assert got.content == expected.content, url
        statuses.add(got.status_code)
    assert statuses >= {200, 400, 404, 422}  # answers and each kind of fault were compared


def test_the_lane_takes_only_routing_gets(clients, town_name: str) -> None:
    """HEAD is the GET without a body; POST bodies, other paths and a trailing slash reach
    the endpoints (or the redirect) as before."""
    with_lane, _ = clients
    a, b = (f"{x!r},{y!r}" for x, y in (xy(10, 0), xy(390, 0)))
    url = f"/networks/{town_name}/route/v1/driving/{a};{b}"
    head, get = with_lane.head(url), with_lane.get(url)
    assert head.status_code == 200 and head.content == b""
    assert head.headers["content-length"] == get.headers["content-length"]
    posted = with_lane.post(f"/networks/{town_name}/route",
                            json={"points": [list(xy(10, 0)), list(xy(390, 0))]})
    assert posted.status_code == 200
    assert posted.json()["routes"][0]["distance"] == get.json()["routes"][0]["distance"]
    slash = with_lane.get(f"/networks/{town_name}/route/", follow_redirects=False)
    assert slash.status_code in (307, 404)
    assert with_lane.get(f"/networks/{town_name}").status_code == 200
