"""The dependencies routers share: a database session per request, and who may call.

Token storage and checking are the core's (:mod:`app.network.tokens`, also used by the command
line); turning a request's ``Authorization`` header into an allowed or refused call is the HTTP
layer's, here.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from app.db.models import TOKEN_ROLES
from app.db.session import get_session, session_scope
from app.errors import ForbiddenError
from app.network.tokens import Principal, authenticate
from app.settings import get_settings

SessionDep = Annotated[Session, Depends(get_session)]


async def read_access(request: Request) -> None:
    """Router dependency for reads: public unless ``UGVMAP_NETWORK_READ_ROLE`` names the least
    role a reader needs (roles rank viewer < editor < admin).

    Asynchronous, with a session of its own only when a role is needed: as a synchronous
    dependency taking a session it cost every read two thread-pool hops before the route's own
    work, and under load (issue 33's heavy mix) a request waited seconds for them before it
    reached its lane and was told 503."""
    if get_settings().network_read_role is None:
        return

    def check() -> None:
        with session_scope() as session:
            check_read_role(request, session)

    await run_in_threadpool(check)


def check_read_role(request: Request, session: Session) -> None:
    """Refuse a reader without the role ``UGVMAP_NETWORK_READ_ROLE`` names (none: anyone)."""
    least = get_settings().network_read_role
    if least is not None:
        allowed = TOKEN_ROLES[TOKEN_ROLES.index(least):]
        require_role(*allowed)(request, session)


def require_role(*roles: str):
    """FastAPI dependency: the caller's Principal, 401 without a valid token, 403 wrong role."""

    def dependency(request: Request, session: SessionDep) -> Principal:
        principal = authenticate(session, request.headers.get("authorization"))
        if principal.role not in roles:
            raise ForbiddenError(
                f"role {principal.role!r} may not do this; needs {' or '.join(roles)}")
        return principal

    return dependency
