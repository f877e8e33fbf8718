"""``/healthz`` says the process is alive; ``/readyz`` says it can serve data.

Readiness checks the database is reachable *and* migrated to the code's head revision, so a
load balancer never routes to an instance whose schema does not match its code. Not ready is
a 503 in the service's one error shape: an unreachable database is the same
``DatabaseUnavailable`` answer every other endpoint gives (``app.errors``).
"""

from __future__ import annotations

from fastapi import APIRouter
from sqlalchemy import text

from app.db.migrate import current_revision, head_revision
from app.db.session import get_engine
from app.errors import SchemaOutOfDateError

router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz() -> dict[str, str]:
    """Liveness: answers as long as the process serves requests, whatever the database does."""
    return {"status": "ok"}


@router.get("/readyz")
def readyz() -> dict[str, str]:
    """Readiness: 200 only when the database answers and its schema is at the code's head."""
    head = head_revision()
    with get_engine().connect() as conn:
        conn.execute(text("SELECT 1"))
        current = current_revision(conn)
    if current != head:
        raise SchemaOutOfDateError(
            f"database schema at {current or 'no revision'}, code expects {head}; "
            "run `ugvmap db upgrade`")
    return {"status": "ready", "schema": current}
