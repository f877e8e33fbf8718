"""Engine and session factory, shared by the HTTP service and the batch jobs.

``pool_pre_ping`` plus a short connect timeout is what lets the service survive the database
going away: requests fail fast with 503 while it is down, and the pool reconnects by itself
once it is back, without a restart.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import lru_cache
from typing import TypeVar

from sqlalchemy import Engine, create_engine
from sqlalchemy.engine import make_url
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session, sessionmaker

from app.errors import ConflictError
from app.settings import get_settings

T = TypeVar("T")
log = logging.getLogger(__name__)
CONFLICTS = frozenset({"40P01", "40001"})
"""SQLSTATEs of transactions that lost to concurrent ones (deadlock_detected,
serialization_failure): rolled back whole, so running them again is safe."""
TRIES = 3
CONFLICT_MESSAGE = ("the write collided with concurrent writes to the same features and "
                    "was rolled back; nothing was changed: send it again")


@lru_cache(maxsize=8)
def get_engine(url: str | None = None) -> Engine:
    """One pooled engine per URL and process (cached): pre-ping drops connections a database restart
    killed, so the service recovers without a restart."""
    settings = get_settings()
    return create_engine(
        url or settings.database_url,
        pool_pre_ping=True,
        pool_size=10,
        max_overflow=20,
        connect_args={"connect_timeout": settings.db_connect_timeout_s},
    )


@lru_cache(maxsize=8)
def _factory(url: str | None) -> sessionmaker[Session]:
    return sessionmaker(get_engine(url), expire_on_commit=False)


@contextmanager
def session_scope(url: str | None = None) -> Iterator[Session]:
    """A transaction: committed when the block ends normally, rolled back on any error."""
    session = _factory(url)()
    try:
        yield session
        session.commit()
    except BaseException:
        session.rollback()
        raise
    finally:
        session.close()


def conflict(exc: BaseException) -> bool:
    """Whether ``exc`` is a transaction that lost to concurrent ones (no database fault)."""
    return getattr(getattr(exc, "orig", None), "sqlstate", None) in CONFLICTS


def retried(work: Callable[[Session], T], url: str | None = None) -> T:
    """``work`` in a transaction (:func:`session_scope`), run again from the start when
    PostgreSQL rolled it back as the loser of a deadlock or a serialization failure, up to
    :data:`TRIES` times in all; then :class:`~app.errors.ConflictError`.

    Why: the edits take their locks in one order (the network's edit lock first), so they
    do not deadlock each other; this is the safety net for what still can (another writer of
    the same rows), and it keeps a lost race from reaching the client as an outage."""
    for attempt in range(1, TRIES + 1):
        try:
            with session_scope(url) as session:
                return work(session)
        except OperationalError as exc:
            if not conflict(exc):
                raise
            log.info("write rolled back by a conflict (try %d of %d): %s", attempt, TRIES,
                     str(exc.orig).splitlines()[0])
            if attempt == TRIES:
                raise ConflictError(CONFLICT_MESSAGE) from exc
    raise AssertionError("unreachable")


def get_session() -> Iterator[Session]:
    """FastAPI dependency: one session per request."""
    with session_scope() as session:
        yield session


def libpq_dsn(url: str) -> str:
    """A libpq/psycopg conninfo URL from a SQLAlchemy URL (for LISTEN threads, COPY, admin)."""
    return make_url(url).set(drivername="postgresql").render_as_string(hide_password=False)
