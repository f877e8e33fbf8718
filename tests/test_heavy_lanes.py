"""Heavy requests in bounded lanes (issue 33 item 6): a few run, a few wait, the next is told
at once to come back (503 + Retry-After) while light requests go on; the whole-network
Lanelet2 map is built once per network version."""

from __future__ import annotations

import asyncio
import gzip
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import psycopg
import pytest

from app.errors import ServiceBusyError
from app.lanelet2 import cache
from app.lanes import Lane, LaneSettings
from testkit import synthetic
from testkit.network_helpers import bearer
from tests.routing_support import dsn, unique, xy


@pytest.fixture()
def street(database_url: str) -> Iterator[dict]:
    with psycopg.connect(dsn(database_url), autocommit=True) as conn:
        name = unique("lanes")
        nid = synthetic.create_network(conn, name)
        first = synthetic.add_line(conn, nid, [xy(0, 0), xy(500, 0)])
        synthetic.add_line(conn, nid, [xy(500, 0), xy(1000, 0)])
        points = ";".join(f"{lon!r},{lat!r}" for lon, lat in (xy(10, 1), xy(990, 1)))
        yield {"name": name, "id": nid, "segment": first, "points": points}


def test_a_lane_runs_some_queues_some_and_refuses_the_rest_at_once() -> None:
    async def scenario() -> None:
        lane = Lane("table", LaneSettings(running=1, waiting=1, retry_after_s=3))
        inside, release = asyncio.Event(), asyncio.Event()
        order: list[str] = []

        async def work(name: str) -> None:
            async with lane.slot():
                order.append(name)
                inside.set()
                await release.wait()

        first = asyncio.create_task(work("first"))
        await inside.wait()
        second = asyncio.create_task(work("second"))
        while lane.waiting == 0:  # the second is queued once it waits for the slot
            await asyncio.sleep(0)
        started = time.monotonic()
        with pytest.raises(ServiceBusyError) as refused:
            async with lane.slot():
                pass
        assert time.monotonic() - started < 0.1
        assert refused.value.retry_after_s == 3 and "table" in refused.value.message
        release.set()
        await asyncio.gather(first, second)
        assert order == ["first", "second"] and lane.waiting == 0
        async with lane.slot():  # free again
            pass

    asyncio.run(scenario())


def test_kinds_share_the_workers_heavy_slots() -> None:
    """Six kinds each with a slot of its own ran six heavy requests at once per worker and
    starved its event loop (issue 33): with one shared slot, a table waits while a match runs,
    counted as waiting in its own lane, and goes on when the match is done."""
    async def scenario() -> None:
        settings = LaneSettings(running=1, waiting=1, total=1)
        shared = asyncio.Semaphore(settings.total)
        match, table = Lane("match", settings, shared), Lane("table", settings, shared)
        inside, release = asyncio.Event(), asyncio.Event()
        order: list[str] = []

        async def work(lane: Lane, name: str) -> None:
            async with lane.slot():
                order.append(name)
                inside.set()
                await release.wait()

        first = asyncio.create_task(work(match, "match"))
        await inside.wait()
        second = asyncio.create_task(work(table, "table"))
        while table.waiting == 0:
            await asyncio.sleep(0)
        await asyncio.sleep(0.05)
        assert order == ["match"]  # the table's own slot is free, the shared one is not
        with pytest.raises(ServiceBusyError):  # its queue (1) is full
            async with table.slot():
                pass
        release.set()
        await asyncio.gather(first, second)
        assert order == ["match", "table"] and table.waiting == 0

    asyncio.run(scenario())


def test_a_full_lane_is_a_503_with_retry_after_while_light_requests_go_on(
        client, street, heavy, monkeypatch: pytest.MonkeyPatch) -> None:
    """A table held in its planner fills the ``table`` lane (1 running, none waiting): the next
    table is refused at once, a route, a tile and /healthz are answered meanwhile, and the
    first table's answer arrives when it is let go."""
    import app.routing.router as routing_router

    heavy(running=1, waiting=0, retry_after_s=4)
    planner = routing_router.plan_table
    inside, release = threading.Event(), threading.Event()

    def held(*args, **kwargs):
        inside.set()
        assert release.wait(60)
        return planner(*args, **kwargs)

    monkeypatch.setattr(routing_router, "plan_table", held)
    table = f"/networks/{street['name']}/table?points={street['points']}"
    with ThreadPoolExecutor(1) as pool:
        first = pool.submit(client.get, table)
        assert inside.wait(60)
        busy = client.get(table)
        assert (busy.status_code, busy.json()["code"]) == (503, "ServiceBusy"), busy.text
        assert busy.headers["retry-after"] == "4"
        osrm = client.get(f"/networks/{street['name']}/table/v1/driving/{street['points']}")
        assert (osrm.status_code, osrm.json()["code"]) == (503, "ServiceBusy")
        # Refused on arrival, before the points are parsed: a POST's body, a GET's points in
        # our URL and in OSRM's (these two were parsed first, and a network version read).
        for bad in (client.post(f"/networks/{street['name']}/table", json={"points": "none"}),
                    client.get(f"/networks/{street['name']}/table?points=none"),
                    client.get(f"/networks/{street['name']}/table/v1/driving/none")):
            assert (bad.status_code, bad.json()["code"]) == (503, "ServiceBusy"), bad.text
        assert client.get(f"/networks/{street['name']}/route?points={street['points']}"
                          ).status_code == 200
        assert client.get(f"/networks/{street['name']}/tiles/14/8260/6041.mvt"
                          ).status_code == 200
        assert client.get("/healthz").status_code == 200
        release.set()
        assert first.result(60).status_code == 200
    assert client.get(table).status_code == 200


def test_the_whole_network_map_is_built_once_per_version(
        client, street, monkeypatch: pytest.MonkeyPatch) -> None:
    """50 clients asking for the whole-network map each built it (median 54 s); now the first
    request of a version builds it and the others are sent the same file."""
    import app.lanelet2.router as lanelet2_router

    builds: list[str] = []
    writer = lanelet2_router.write_lanelet2

    def counted(selection, *args, **kwargs):
        builds.append(selection.name)
        return writer(selection, *args, **kwargs)

    monkeypatch.setattr(lanelet2_router, "write_lanelet2", counted)
    url = f"/networks/{street['name']}/lanelet2.osm"
    first, again = client.get(url), client.get(url)
    assert first.status_code == again.status_code == 200
    assert first.content == again.content and len(builds) == 1
    assert first.headers["x-lanelet2-origin"] == again.headers["x-lanelet2-origin"]
    assert first.headers["content-disposition"].endswith(f'{street["name"]}.lanelet2.osm"')
    # An origin of its own is another map; a bbox is built each time.
    assert client.get(url, params={"origin": "42.5,1.5"}).status_code == 200
    assert len(builds) == 2
    edit = client.patch(f"/collections/{street['name']}-segments/items/{street['segment']}",
                        json={"name": "Edited"}, headers=bearer("editor"))
    assert edit.status_code == 200, edit.text
    changed = client.get(url)
    assert changed.status_code == 200 and len(builds) == 3
    assert 'k="name" v="Edited"' in changed.text and 'v="Edited"' not in first.text


def test_the_whole_network_map_is_sent_as_stored_gzip(client, street) -> None:
    """A client that accepts gzip is sent the map's gzip file as it was stored (compressing
    a 40 MB map chunk by chunk on the event loop for every download starved light requests,
    issue 33); one that does not is sent the plain map; both are the same map."""
    url = f"/networks/{street['name']}/lanelet2.osm"
    plain = client.get(url, headers={"Accept-Encoding": "identity"})
    assert plain.status_code == 200 and "content-encoding" not in plain.headers
    packed = client.get(url, headers={"Accept-Encoding": "gzip"})
    assert packed.status_code == 200, packed.text
    assert packed.headers["content-encoding"] == "gzip"
    assert "Accept-Encoding" in packed.headers["vary"]
    assert packed.headers["x-lanelet2-origin"] == plain.headers["x-lanelet2-origin"]
    assert packed.content == plain.content  # httpx decoded it
    stored = next(cache.cache_dir().glob(f"{street['id']}-v*.osm.gz")).read_bytes()
    assert int(packed.headers["content-length"]) == len(stored)
    assert gzip.decompress(stored) == plain.content


@pytest.mark.parametrize("stage", ["legs", "isochrone"])
def test_the_time_budget_covers_every_stage_of_a_match_and_an_isochrone(
        client, street, limits, monkeypatch: pytest.MonkeyPatch, stage: str) -> None:
    """The budget was checked only in the match's Viterbi loop (and not at all in an
    isochrone): a 5,000-point match spent three times as long again around it, answering
    ``TooBig`` only after 30-46 s. A stage that overruns the budget (made slow here by
    sleeping past it) now ends the request with ``TooBig`` too."""
    import app.routing.engine as engine
    import app.routing.isochrone as isochrone

    limits(time_budget_s=0.05)
    patched = (engine.Router, "leg") if stage == "legs" else (isochrone, "reachable")
    original = getattr(*patched)

    def slow(*args, **kwargs):
        time.sleep(0.1)  # longer than the whole budget: it is spent once this returns
        return original(*args, **kwargs)

    monkeypatch.setattr(*patched, slow)
    if stage == "legs":
        trace = ";".join(f"{lon!r},{lat!r}" for lon, lat in (xy(x, 1) for x in (10, 60, 110)))
        r = client.get(f"/networks/{street['name']}/match", params={"points": trace})
    else:
        lon, lat = xy(10, 1)
        r = client.get(f"/networks/{street['name']}/isochrone",
                       params={"point": f"{lon!r},{lat!r}", "seconds": "60"})
    assert (r.status_code, r.json()["code"]) == (400, "TooBig"), r.text
    assert "time budget (0.05 s)" in r.json()["message"]
