"""``/healthz`` says the process is alive; ``/readyz`` says it can serve data.

Readiness checks the database is reachable *and* migrated to the code's head revision, so a
load balancer never routes to an instance whose schema does not match its code.
"""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse
from sqlalchemy import text
from sqlalchemy.exc import SQLAlchemyError

from app.db.migrate import current_revision, head_revision
from app.db.session import get_engine

router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz() -> dict[str, str]:
    return {"status": "ok"}


@router.get("/readyz")
def readyz() -> JSONResponse:
    head = head_revision()
    try:
        with get_engine().connect() as conn:
            conn.execute(text("SELECT 1"))
            current = current_revision(conn)
    except SQLAlchemyError as exc:
        reason = str(exc.orig if hasattr(exc, "orig") and exc.orig else exc).strip()
        return JSONResponse(
            {"status": "unavailable", "reason": f"database unreachable: {reason.splitlines()[0]}"},
            status_code=503,
        )
    if current != head:
        return JSONResponse(
            {"status": "unavailable",
             "reason": f"database schema at {current or 'no revision'}, code expects {head}; "
                       "run `ugvmap db upgrade`"},
            status_code=503,
        )
    return JSONResponse({"status": "ready", "schema": current})
