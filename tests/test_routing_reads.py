"""The version read routing requests make on the event loop (app.routing.reads): the row it
reads, 404 and 503, a pooled connection that died while idle, the CLI's own reads, and which
routes are planned on the loop."""

from __future__ import annotations

import asyncio
import uuid

import psycopg
import pytest

from app.db.session import libpq_dsn
from app.errors import DatabaseUnavailableError, NotFoundError
from app.routing.reads import VersionReader, read_connection
from testkit.server import free_port
from testkit.synthetic import create_network


@pytest.fixture()
def network(database_url: str) -> tuple[str, int]:
    name = f"reads-{uuid.uuid4().hex[:8]}"
    with psycopg.connect(libpq_dsn(database_url), autocommit=True) as conn:
        return name, create_network(conn, name)


def test_reads_the_version_and_sees_the_next_edit(database_url, network) -> None:
    name, net = network
    reader = VersionReader(database_url)
    first = asyncio.run(reader.read(name))
    assert (first.name, first.network_id) == (name, net)
    assert first.network(name) == (net, first.version)
    with psycopg.connect(libpq_dsn(database_url), autocommit=True) as conn:
        conn.execute("UPDATE networks SET version = version + 1 WHERE id = %s", (net,))
    assert asyncio.run(reader.read(name)).version == first.version + 1  # same pooled conn


def test_unknown_network_is_404(database_url) -> None:
    with pytest.raises(NotFoundError):
        asyncio.run(VersionReader(database_url).read("no-such-network"))


def test_a_connection_killed_while_idle_is_replaced(database_url, network) -> None:
    name, net = network
    reader = VersionReader(database_url)

    async def twice() -> tuple[int, int]:
        await reader.read(name)
        with psycopg.connect(libpq_dsn(database_url), autocommit=True) as conn:
            killed = conn.execute(
                "SELECT pg_terminate_backend(pid) FROM pg_stat_activity WHERE "
                "datname = current_database() AND pid <> pg_backend_pid() AND "
                "query LIKE 'SELECT id, version FROM networks%%'").fetchall()
        assert killed and all(ok for (ok,) in killed)
        again = await reader.read(name)
        return again.network_id, again.version

    assert asyncio.run(twice())[0] == net


def test_unreachable_database_is_503() -> None:
    reader = VersionReader(f"postgresql://postgres@127.0.0.1:{free_port()}/nothing")
    with pytest.raises(DatabaseUnavailableError, match="database unreachable"):
        asyncio.run(reader.read("any"))


def test_cli_reads_on_its_own_connection(database_url, network) -> None:
    name, net = network
    with read_connection(database_url) as reads:
        assert reads.network(name)[0] == net
        with pytest.raises(NotFoundError):
            reads.network("no-such-network")


def test_quick_routes_are_planned_on_the_event_loop(client, database_url, monkeypatch) -> None:
    """A route of two points on a small network with everything built is planned without a
    worker thread; one with alternatives (several searches) is not."""
    from app.routing import router
    from testkit import synthetic

    name = f"quick-{uuid.uuid4().hex[:8]}"
    with psycopg.connect(libpq_dsn(database_url), autocommit=True) as conn:
        synthetic.grid(conn, name, 6, 6, origin=(1.7, 42.7))
    hops: list[str] = []
    real = router.run_in_threadpool

    async def counted(func, *args, **kwargs):
        hops.append(func.__name__)
        return await real(func, *args, **kwargs)

    monkeypatch.setattr(router, "run_in_threadpool", counted)
    url = f"/networks/{name}/route/v1/driving/1.7001,42.7001;1.7049,42.7035"
    assert client.get(url).status_code == 200  # loads the graph: in a thread
    assert client.get(url, params={"steps": "true"}).status_code == 200  # builds junctions
    assert len(hops) == 2
    for params in ({}, {"steps": "true", "geometries": "geojson", "overview": "full"}):
        assert client.get(url, params=params).status_code == 200
    assert len(hops) == 2  # both on the loop
    assert client.get(url, params={"alternatives": "2"}).status_code == 200
    assert len(hops) == 3


def test_an_abandoned_read_closes_its_connection(database_url, network) -> None:
    """A read sent and never waited for (the planner beside it failed) leaves no connection
    with an unread answer in the pool."""
    name, _ = network
    reader = VersionReader(database_url)
    asyncio.run(reader.read(name))  # one idle connection now
    pending = reader.begin(name)
    pending.abandon()
    assert pending._conn is not None and pending._conn.closed
    assert asyncio.run(reader.read(name)).name == name  # on a new connection
