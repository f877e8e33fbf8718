"""``/healthz`` says the process is alive; ``/readyz`` says it can serve data.

Readiness checks the database is reachable, migrated to the code's head revision, and that
this instance reads the raster store the database's files are in (migration 0009), so a
load balancer never routes to an instance whose schema or store does not match. Not ready is
a 503 in the service's one error shape: an unreachable database is the same
``DatabaseUnavailable`` answer every other endpoint gives (``app.errors``).
"""

from __future__ import annotations

import logging

from fastapi import APIRouter
from sqlalchemy import text

from app import errors
from app.api.errors import responses
from app.db.migrate import current_revision, head_revision
from app.db.session import get_engine
from app.errors import SchemaOutOfDateError, StoreMismatchError
from app.tiles.store import mismatch, recorded_root, store_root

log = logging.getLogger(__name__)

router = APIRouter(tags=["health"])


@router.get("/healthz")
async def healthz() -> dict[str, str]:
    """Liveness: answers as long as the process serves requests, whatever the database does."""
    return {"status": "ok"}


@router.get("/readyz", responses=responses(errors.DatabaseUnavailableError,
                                                 SchemaOutOfDateError, StoreMismatchError))
def readyz() -> dict[str, str]:
    """Readiness: 200 only when the database answers, its schema is at the code's head, and
    this process reads the raster store the database's files are in."""
    head = head_revision()
    with get_engine().connect() as conn:
        conn.execute(text("SELECT 1"))
        current = current_revision(conn)
        recorded = recorded_root(conn) if current == head else None
    if current != head:
        raise SchemaOutOfDateError(
            f"database schema at {current or 'no revision'}, code expects {head}; "
            "run `ugvmap db upgrade`")
    if recorded is not None and recorded != store_root():
        log.error("not ready: %s", mismatch(recorded, store_root()))
        raise StoreMismatchError("this process's raster store is not the one the database's "
                                 "files are in (the server log names both)")
    return {"status": "ready", "schema": current}
