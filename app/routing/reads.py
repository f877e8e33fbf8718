"""The database reads of a routing request, on a small pool of autocommit connections.

Every request reads the network's id and version, so that it routes on a graph holding every
edit committed before it (:mod:`app.routing.live`), and nothing else: snapping happens in
memory (:mod:`app.routing.nearby`), and the graph holds the OSM tags steps need.

Why not the service's SQLAlchemy engine: its pool pings each connection on checkout, a round
trip as long as the version read itself, and its statement layer costs more than the read.
Here a request takes an idle psycopg connection (autocommit: one statement needs no
BEGIN/COMMIT) and runs prepared statements on it. A connection that broke while idle (the
database restarted) is dropped and the read retried once on a fresh one, which is what the
ping bought; a database that cannot be reached is a 503 the client may retry.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import psycopg

from app.db.session import libpq_dsn
from app.errors import DatabaseUnavailableError, NotFoundError
from app.settings import get_settings

MAX_IDLE = 8  # connections kept per process; a burst beyond opens (and then closes) more
NETWORK_SQL = "SELECT id, version FROM networks WHERE name = %s"


class Reads:
    """One request's reads, on one pooled connection."""

    def __init__(self, pool: ReadPool, conn: psycopg.Connection, reused: bool) -> None:
        self._pool, self.conn, self._reused = pool, conn, reused

    def _rows(self, sql: str, args: Sequence[Any]) -> list[tuple[Any, ...]]:
        try:
            return self.conn.execute(sql, args, prepare=True).fetchall()
        except psycopg.OperationalError:
            if not self._reused:
                raise
            self.conn.close()  # broke while idle: one retry on a fresh connection
            self.conn, self._reused = self._pool.connect(), False
            return self.conn.execute(sql, args, prepare=True).fetchall()

    def network(self, name: str) -> tuple[int, int]:
        """(id, version) of the network ``name``; 404 when there is none."""
        rows = self._rows(NETWORK_SQL, (name,))
        if not rows:
            raise NotFoundError(f"network {name!r} does not exist")
        return int(rows[0][0]), int(rows[0][1])


class ReadPool:
    """Idle autocommit connections to one database, shared by a process's request threads."""

    def __init__(self, database_url: str) -> None:
        self._dsn = libpq_dsn(database_url)
        self._idle: list[psycopg.Connection] = []
        self._lock = threading.Lock()

    def connect(self) -> psycopg.Connection:
        """A new connection, or 503 when the database cannot be reached."""
        try:
            return psycopg.connect(self._dsn, autocommit=True,
                                   connect_timeout=get_settings().db_connect_timeout_s)
        except psycopg.OperationalError as exc:
            raise unavailable(exc) from exc

    @contextmanager
    def reads(self) -> Iterator[Reads]:
        """A request's reads on an idle connection (or a new one), given back afterwards
        unless it broke."""
        with self._lock:
            conn = self._idle.pop() if self._idle else None
        reads = Reads(self, conn, True) if conn is not None else Reads(self, self.connect(),
                                                                          False)
        try:
            yield reads
        except psycopg.OperationalError as exc:
            reads.conn.close()
            raise unavailable(exc) from exc
        except BaseException:
            self._give_back(reads.conn)
            raise
        self._give_back(reads.conn)

    def _give_back(self, conn: psycopg.Connection) -> None:
        if conn.closed or conn.info.transaction_status != psycopg.pq.TransactionStatus.IDLE:
            conn.close()
            return
        with self._lock:
            if len(self._idle) < MAX_IDLE:
                self._idle.append(conn)
                return
        conn.close()


def unavailable(exc: Exception) -> DatabaseUnavailableError:
    """The 503 every endpoint answers when the database is unreachable, with the reason."""
    detail = (str(exc).strip().splitlines() or ["no reason given"])[0]
    return DatabaseUnavailableError(f"database unreachable: {detail}")


_pools: dict[str, ReadPool] = {}
_pools_lock = threading.Lock()


@contextmanager
def read_connection(database_url: str | None = None) -> Iterator[Reads]:
    """The reads of one routing request (or CLI command) on the configured database."""
    url = database_url or get_settings().database_url
    with _pools_lock:
        if url not in _pools:
            _pools[url] = ReadPool(url)
        pool = _pools[url]
    with pool.reads() as reads:
        yield reads
