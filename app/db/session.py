"""Engine and session factory, shared by the HTTP service and the batch jobs.

``pool_pre_ping`` plus a short connect timeout is what lets the service survive the database
going away: requests fail fast with 503 while it is down, and the pool reconnects by itself
once it is back, without a restart.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from functools import lru_cache

from sqlalchemy import Engine, create_engine
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

from app.settings import get_settings


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


def get_session() -> Iterator[Session]:
    """FastAPI dependency: one session per request."""
    with session_scope() as session:
        yield session


def libpq_dsn(url: str) -> str:
    """A libpq/psycopg conninfo URL from a SQLAlchemy URL (for LISTEN threads, COPY, admin)."""
    return make_url(url).set(drivername="postgresql").render_as_string(hide_password=False)
