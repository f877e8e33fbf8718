"""``GET /jobs`` and ``GET /jobs/{id}``: what the batch jobs are doing or did."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query
from sqlalchemy import text
from sqlalchemy.orm import Session

from app.db.models import JOB_STATUSES
from app.db.session import get_session
from app.errors import InvalidParameterValueError, NotFoundError

router = APIRouter(tags=["jobs"])
SessionDep = Annotated[Session, Depends(get_session)]
COLUMNS = ("id, kind, target, params, status, progress, message, error, created_at, "
           "started_at, finished_at")


def _job(row: Any) -> dict[str, Any]:
    job = dict(row._mapping)
    for key in ("created_at", "started_at", "finished_at"):
        job[key] = job[key].isoformat() if job[key] else None
    return job


@router.get("/jobs")
def list_jobs(session: SessionDep,
              status: Annotated[str | None, Query(description="queued|running|...")] = None,
              limit: Annotated[int, Query(ge=1, le=500)] = 50) -> dict[str, Any]:
    """Most recent jobs first."""
    if status is not None and status not in JOB_STATUSES:
        raise InvalidParameterValueError(f"status must be one of {', '.join(JOB_STATUSES)}")
    rows = session.execute(text(
        f"SELECT {COLUMNS} FROM ingest_jobs WHERE (CAST(:s AS text) IS NULL OR status = :s) "
        "ORDER BY id DESC LIMIT :limit"), {"s": status, "limit": limit})
    return {"jobs": [_job(r) for r in rows]}


@router.get("/jobs/{job_id}")
def get_job(job_id: int, session: SessionDep) -> dict[str, Any]:
    """One job row; ids outside bigint are simply not found (never a database error)."""
    row = None
    if 0 < job_id < 2**63:
        row = session.execute(text(f"SELECT {COLUMNS} FROM ingest_jobs WHERE id = :id"),
                              {"id": job_id}).first()
    if row is None:
        raise NotFoundError(f"job {job_id} not found")
    return _job(row)
