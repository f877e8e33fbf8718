"""The one database read of a routing request: the network's id and version.

Every request reads ``networks.version``, so that it routes on a graph holding every edit
committed before it (:mod:`app.routing.live`), and nothing else: snapping happens in memory
(:mod:`app.routing.nearby`), and the graph holds the OSM tags steps need.

An HTTP request reads it on the event loop (:class:`VersionReader`): libpq's non-blocking
calls (``psycopg.pq``) on an idle autocommit connection with a prepared statement, the loop
waiting for the socket like for any other. The query is sent first
(:meth:`VersionReader.begin`) and its answer awaited after a quick plan made meanwhile
(``app.routing.router._answer``). Why not in the worker thread with the rest of the request:
a read there kept the planner in a thread even when the planner itself is a millisecond
(:mod:`app.routing.planner` answers those on the loop), and psycopg's statement layer cost
more CPU than the round trip (21 us against 5 us in the client per read). Why not psycopg's
async connection: its waiting machinery cost ~0.15 ms of the loop per read.

A connection that broke while idle (the database restarted) is dropped and the read retried
once on a fresh one; a database that cannot be reached is a 503 the client may retry. New
connections are opened in a worker thread (connecting blocks), only when none is idle.

The CLI reads the same on a connection of its own (:func:`read_connection`).
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Protocol

import anyio.to_thread
import psycopg
from psycopg import pq

from app.db.session import libpq_dsn
from app.errors import DatabaseUnavailableError, NotFoundError
from app.settings import get_settings

MAX_IDLE = 8  # connections kept per process; a burst beyond opens (and then closes) more
NETWORK_SQL = "SELECT id, version FROM networks WHERE name = %s"
STATEMENT = b"ugvmap_network_version"  # NETWORK_SQL, prepared on each pooled connection
STATEMENT_SQL = b"SELECT id, version FROM networks WHERE name = $1"


class Reads(Protocol):
    """What planners read from the database."""

    def network(self, name: str) -> tuple[int, int]:
        """(id, version) of the network ``name``; 404 when there is none."""
        ...


@dataclass(frozen=True)
class ReadAhead:
    """A request's version read, done before its planner runs."""

    name: str
    network_id: int
    version: int

    def network(self, name: str) -> tuple[int, int]:
        """(id, version) of the network read, which must be ``name``."""
        if name != self.name:
            raise ValueError(f"read {self.name!r}, asked for {name!r}")
        return self.network_id, self.version


class VersionReader:
    """Idle connections to one database on which the event loop reads versions."""

    def __init__(self, database_url: str) -> None:
        self._dsn = libpq_dsn(database_url)
        self._idle: list[psycopg.Connection] = []
        self._lock = threading.Lock()  # several loops (test clients) may share a reader
        self._ids: dict[str, int] = {}  # network id of each name as last read

    def known_id(self, name: str) -> int | None:
        """The id ``name`` had when this reader last read it (``None``: never read): which
        graph a plan made before the read returns may use. A network deleted and created again
        under the same name gets a new id, which the read then tells."""
        return self._ids.get(name)

    async def read(self, name: str) -> ReadAhead:
        """The network's id and version (404 when there is none, 503 when the database cannot
        be reached)."""
        return await self.begin(name).result()

    def begin(self, name: str) -> PendingRead:
        """Send the read now when an idle connection is at hand (its answer is awaited with
        :meth:`PendingRead.result`): whatever the caller does meanwhile overlaps the database's
        round trip."""
        with self._lock:
            conn = self._idle.pop() if self._idle else None
        failure = None
        if conn is not None:
            try:
                _send(conn.pgconn, name)
            except psycopg.OperationalError as exc:
                failure = exc  # broke while idle: result() retries on a fresh connection
        return PendingRead(self, name, conn, failure)

    async def _connect(self) -> psycopg.Connection:
        return await anyio.to_thread.run_sync(self._open)

    def _open(self) -> psycopg.Connection:
        conn = psycopg.connect(self._dsn, autocommit=True,
                               connect_timeout=get_settings().db_connect_timeout_s)
        prepared = conn.pgconn.prepare(STATEMENT, STATEMENT_SQL)
        if prepared.status != pq.ExecStatus.COMMAND_OK:
            conn.close()
            raise psycopg.errors.error_from_result(prepared)
        conn.pgconn.nonblocking = 1
        return conn

    def _give_back(self, conn: psycopg.Connection) -> None:
        with self._lock:
            if len(self._idle) < MAX_IDLE:
                self._idle.append(conn)
                return
        conn.close()


class PendingRead:
    """A version read on its way: the connection it was sent on (``None`` when none was idle:
    :meth:`result` opens one) or why sending failed."""

    def __init__(self, reader: VersionReader, name: str, conn: psycopg.Connection | None,
                 failure: psycopg.OperationalError | None) -> None:
        self._reader, self._name, self._conn, self._failure = reader, name, conn, failure

    async def result(self) -> ReadAhead:
        """The network's id and version (404 when there is none, 503 when the database cannot
        be reached)."""
        reader, name, conn = self._reader, self._name, self._conn
        reused = conn is not None
        try:
            if conn is None:
                conn = await reader._connect()
                _send(conn.pgconn, name)
            try:
                if self._failure is not None:
                    raise self._failure
                row = await _receive(conn.pgconn)
            except psycopg.OperationalError:
                conn.close()
                if not reused:
                    raise
                conn = await reader._connect()  # broke while idle: one retry on a fresh one
                _send(conn.pgconn, name)
                row = await _receive(conn.pgconn)
        except psycopg.OperationalError as exc:
            if conn is not None:
                conn.close()
            raise unavailable(exc) from exc
        except BaseException:  # cancelled mid-read: the connection's state is unknown
            if conn is not None:
                conn.close()
            raise
        reader._give_back(conn)
        if row is None:
            raise NotFoundError(f"network {name!r} does not exist")
        reader._ids[name] = row[0]
        return ReadAhead(name, *row)

    def abandon(self) -> None:
        """Drop a read whose answer nobody will wait for (its connection's state is unknown)."""
        if self._conn is not None:
            self._conn.close()


def _send(pg: pq.abc.PGconn, name: str) -> None:
    """Send the prepared read on a non-blocking connection (what does not fit in the socket
    yet leaves in :func:`_receive`)."""
    pg.send_query_prepared(STATEMENT, [name.encode()])


async def _receive(pg: pq.abc.PGconn) -> tuple[int, int] | None:
    """The answer of the read :func:`_send` sent, waiting on the event loop."""
    while pg.flush():  # 1: the rest of the query waits for room in the socket
        await _socket_ready(pg.socket, write=True)
    while True:
        pg.consume_input()
        if not pg.is_busy():
            break
        await _socket_ready(pg.socket, write=False)
    result = pg.get_result()
    while pg.get_result() is not None:  # the end of the query's results
        pass
    if result is None or result.status != pq.ExecStatus.TUPLES_OK:
        if result is None:
            raise psycopg.OperationalError("the database sent no result")
        raise psycopg.errors.error_from_result(result)
    if not result.ntuples:
        return None
    network_id, version = result.get_value(0, 0), result.get_value(0, 1)
    assert network_id is not None and version is not None
    return int(network_id), int(version)


async def _socket_ready(fd: int, write: bool) -> None:
    """Until the event loop sees ``fd`` readable (or writable)."""
    loop = asyncio.get_running_loop()
    ready = loop.create_future()

    def wake() -> None:
        if not ready.done():
            ready.set_result(None)

    (loop.add_writer if write else loop.add_reader)(fd, wake)
    try:
        await ready
    finally:
        (loop.remove_writer if write else loop.remove_reader)(fd)


def unavailable(exc: Exception) -> DatabaseUnavailableError:
    """The 503 every endpoint answers when the database is unreachable, with the reason."""
    detail = (str(exc).strip().splitlines() or ["no reason given"])[0]
    return DatabaseUnavailableError(f"database unreachable: {detail}")


_readers: dict[str, VersionReader] = {}
_readers_lock = threading.Lock()


def version_reader(database_url: str | None = None) -> VersionReader:
    """The process's reader for the configured database (or ``database_url``)."""
    url = database_url or get_settings().database_url
    with _readers_lock:
        if url not in _readers:
            _readers[url] = VersionReader(url)
        return _readers[url]


class _ConnectionReads:
    """The reads of one command on its own connection."""

    def __init__(self, conn: psycopg.Connection) -> None:
        self._conn = conn

    def network(self, name: str) -> tuple[int, int]:
        """(id, version) of the network ``name``; 404 when there is none."""
        row = self._conn.execute(NETWORK_SQL, (name,)).fetchone()
        if row is None:
            raise NotFoundError(f"network {name!r} does not exist")
        return int(row[0]), int(row[1])


@contextmanager
def read_connection(database_url: str | None = None) -> Iterator[Reads]:
    """The reads of one CLI command, on a connection of its own; 503 when the database cannot
    be reached."""
    url = database_url or get_settings().database_url
    try:
        with psycopg.connect(libpq_dsn(url), autocommit=True,
                             connect_timeout=get_settings().db_connect_timeout_s) as conn:
            yield _ConnectionReads(conn)
    except psycopg.OperationalError as exc:
        raise unavailable(exc) from exc
