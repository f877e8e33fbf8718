"""API tokens: created once by an admin on the CLI, stored only as a SHA-256 hash.

A token is 256 random bits, so a fast unsalted hash is enough (nothing to brute-force), and
it lets a request find its token with one indexed lookup.
"""

from __future__ import annotations

import hashlib
import secrets
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Request
from sqlalchemy import text
from sqlalchemy.orm import Session

from app.db.models import TOKEN_ROLES
from app.db.session import get_session
from app.errors import ForbiddenError, UnauthorizedError, UserError
from app.settings import get_settings

SessionDep = Annotated[Session, Depends(get_session)]
PREFIX = "ugv_"
MAX_NAME = 200


@dataclass(frozen=True)
class Principal:
    """Who is making a change: recorded as ``updated_by`` / ``edited_by``."""

    name: str
    role: str


def hash_token(token: str) -> str:
    """SHA-256 of a token: tokens are random and long, so a fast hash is enough and lookups stay
    indexed."""
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()


def create_token(session: Session, name: str, role: str) -> str:
    """Store a new token and return its plaintext, which is never stored or shown again."""
    if role not in TOKEN_ROLES:
        raise UserError(f"role must be one of {', '.join(TOKEN_ROLES)}")
    if not name.strip() or len(name) > MAX_NAME:
        raise UserError(f"token name must be 1..{MAX_NAME} characters")
    token = PREFIX + secrets.token_urlsafe(32)
    session.execute(text("INSERT INTO api_tokens (name, token_hash, role) "
                         "VALUES (:n, :h, :r)"), {"n": name, "h": hash_token(token), "r": role})
    return token


def authenticate(session: Session, authorization: str | None) -> Principal:
    """The principal a bearer token belongs to; 401 with a challenge when it is missing, unknown or
    revoked."""
    scheme, _, token = (authorization or "").partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        raise UnauthorizedError("an 'Authorization: Bearer <token>' header is required")
    row = session.execute(text("SELECT name, role FROM api_tokens WHERE token_hash = :h "
                               "AND revoked_at IS NULL"),
                          {"h": hash_token(token.strip())}).first()
    if row is None:
        raise UnauthorizedError("the token is unknown or revoked")
    return Principal(row.name, row.role)


def read_access(request: Request, session: SessionDep) -> None:
    """Router dependency for reads: public unless ``UGVMAP_NETWORK_READ_ROLE`` names the least
    role a reader needs (roles rank viewer < editor < admin)."""
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
