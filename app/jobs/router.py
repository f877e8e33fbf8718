"""``GET /jobs``, ``GET /jobs/{id}``: what the batch jobs are doing or did; ``POST /jobs``:
queue one (admin).

Who reads: ``UGVMAP_JOBS_READ_ROLE`` (or, unset, ``UGVMAP_NETWORK_READ_ROLE``) names the least
token role; with neither, the list is public. Only admins see rows as stored: everyone else
gets file names instead of absolute server paths (:mod:`app.jobs.redact`) and no worker host,
since progress is useful to anyone waiting for a layer but the server's layout is not.
Listing also marks failed the jobs whose process died (:func:`~app.jobs.lease.reap_dead_jobs`).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from sqlalchemy.orm import Session

from app import errors
from app.api.dependencies import require_role
from app.api.errors import PayloadTooLargeError, UnsupportedMediaTypeError, responses
from app.db.models import JOB_STATUSES, TOKEN_ROLES
from app.db.session import get_session, session_scope
from app.errors import InvalidParameterValueError, InvalidValueError, NotFoundError
from app.jobs.queue import enqueue
from app.jobs.redact import strip_paths
from app.jobs.rows import read_jobs
from app.network.editing_router import json_body
from app.network.tokens import Principal, authenticate
from app.params import Shape
from app.settings import get_settings

# Any read may need a token (jobs read role) and may find the database gone; every request
# may carry a malformed query or path value.
router = APIRouter(tags=["jobs"], responses=responses(
    errors.InvalidParameterValueError, errors.UnauthorizedError, errors.ForbiddenError,
    errors.InvalidValueError, errors.DatabaseUnavailableError))
SessionDep = Annotated[Session, Depends(get_session)]


def jobs_reader(request: Request, session: SessionDep) -> Principal | None:
    """Router dependency: who is reading (None: anonymous, allowed when the list is public)."""
    least = get_settings().jobs_role
    if least is not None:
        return require_role(*TOKEN_ROLES[TOKEN_ROLES.index(least):])(request, session)
    header = request.headers.get("authorization")
    return authenticate(session, header) if header else None


ReaderDep = Annotated[Principal | None, Depends(jobs_reader)]


def job_view(row: Any, reader: Principal | None) -> dict[str, Any]:
    """One job row as JSON, stripped of server paths and hosts unless ``reader`` is admin."""
    job = dict(row._mapping)
    for key in ("created_at", "started_at", "finished_at", "heartbeat_at"):
        job[key] = job[key].isoformat() if job[key] else None
    if reader is not None and reader.role == "admin":
        return job
    job.pop("worker")
    return strip_paths(job)


@router.get("/jobs")
def list_jobs(session: SessionDep, reader: ReaderDep,
              status: Annotated[str | None, Shape(enum=list(JOB_STATUSES)),
                                Query(description="only jobs in this state")] = None,
              limit: Annotated[int, Query(ge=1, le=500)] = 50) -> dict[str, Any]:
    """Most recent jobs first."""
    if status is not None and status not in JOB_STATUSES:
        raise InvalidParameterValueError(f"status must be one of {', '.join(JOB_STATUSES)}")
    rows = read_jobs(session.connection(), status=status, limit=limit)
    return {"jobs": [job_view(r, reader) for r in rows]}


@router.get("/jobs/{job_id}", responses=responses(errors.NotFoundError))
def get_job(job_id: int, session: SessionDep, reader: ReaderDep) -> dict[str, Any]:
    """One job row; ids outside bigint are simply not found (never a database error)."""
    rows = read_jobs(session.connection(), job_id=job_id) if 0 < job_id < 2**63 else []
    if not rows:
        raise NotFoundError(f"job {job_id} not found")
    return job_view(rows[0], reader)


@router.post("/jobs", status_code=202, openapi_extra={"security": [{"bearer": []}]},
             responses=responses(PayloadTooLargeError,
                                        UnsupportedMediaTypeError))
async def post_job(request: Request,
                   admin: Annotated[Principal, Depends(require_role("admin"))]) -> JSONResponse:
    """Queue a job for ``ugvmap worker``: ``{"kind": "ingest-raster", "params": {...}}``.
    Its parameters are checked first (422 per field; nothing queued); 202 with the job row."""
    body = await json_body(request, ("application/json",))
    if not isinstance(body, dict) or set(body) - {"kind", "params"}:
        raise InvalidValueError("the body must be {\"kind\": ..., \"params\": {...}}",
                                errors={"body": "must have only 'kind' and 'params'"})

    def queue() -> dict[str, Any]:
        with session_scope() as session:
            job_id = enqueue(session, body.get("kind"), body.get("params", {}))
            return job_view(read_jobs(session.connection(), job_id=job_id)[0], admin)

    job = await run_in_threadpool(queue)
    return JSONResponse(job, status_code=202, headers={"Location": f"/jobs/{job['id']}"})
