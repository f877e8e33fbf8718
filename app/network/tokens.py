"""API tokens: created once by an admin on the CLI, stored only as a SHA-256 hash.

A token is 256 random bits, so a fast unsalted hash is enough (nothing to brute-force), and
it lets a request find its token with one indexed lookup.

Lifecycle: ``ugvmap tokens create [--expires 30d]``, ``tokens list``, ``tokens revoke``. Every
request reads its token's row (revocation, expiry) from the database; nothing about a token's
validity is cached in a worker, so a revoked or expired token is refused at once by every
worker. ``last_used_at`` is written at most once per :data:`TOUCH_EVERY_S` per token, in its
own short transaction: a busy client costs one small UPDATE a minute, not one per request,
and the request's own transaction never holds a lock on the token row.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import re
import secrets
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.db.models import TOKEN_ROLES
from app.errors import UnauthorizedError, UserError

PREFIX = "ugv_"
MAX_NAME = 200
TOUCH_EVERY_S = 60
DURATION_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 7 * 86400}


@dataclass(frozen=True)
class Principal:
    """Who is making a change: recorded as ``updated_by`` / ``edited_by``."""

    name: str
    role: str


def hash_token(token: str) -> str:
    """SHA-256 of a token: tokens are random and long, so a fast hash is enough and lookups stay
    indexed."""
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()


def parse_duration(text_: str) -> timedelta:
    """``30d`` / ``12h`` / ``90m`` / ``2w`` / ``45s`` -> timedelta (a token's lifetime)."""
    match = re.fullmatch(r"([0-9]{1,6})([smhdw])", text_.strip())
    if not match or int(match[1]) == 0:
        raise UserError(f"duration {text_[:40]!r}: use a positive number and a unit "
                        "s, m, h, d or w, e.g. 30d")
    return timedelta(seconds=int(match[1]) * DURATION_UNITS[match[2]])


def create_token(session: Session, name: str, role: str,
                 expires_in: timedelta | None = None) -> str:
    """Store a new token and return its plaintext, which is never stored or shown again."""
    if role not in TOKEN_ROLES:
        raise UserError(f"role must be one of {', '.join(TOKEN_ROLES)}")
    if not name.strip() or len(name) > MAX_NAME or not name.isprintable():
        raise UserError(f"token name must be 1..{MAX_NAME} printable characters")
    token = PREFIX + secrets.token_urlsafe(32)
    session.execute(text(
        "INSERT INTO api_tokens (name, token_hash, role, expires_at) VALUES (:n, :h, :r, "
        "now() + make_interval(secs => :s))"),
        {"n": name, "h": hash_token(token), "r": role,
         "s": None if expires_in is None else expires_in.total_seconds()})
    return token


def list_tokens(session: Session) -> list[dict[str, Any]]:
    """Every token (never its secret), oldest first, with its state: active, expired or
    revoked."""
    rows = session.execute(text(
        "SELECT id, name, role, created_at, last_used_at, expires_at, revoked_at, "
        "CASE WHEN revoked_at IS NOT NULL THEN 'revoked' "
        "     WHEN expires_at <= now() THEN 'expired' ELSE 'active' END AS state "
        "FROM api_tokens ORDER BY id")).all()
    return [dict(r._mapping) for r in rows]


def revoke_token(session: Session, ref: str) -> dict[str, Any]:
    """Revoke the token with id ``ref`` or the one active token named ``ref``; return its row.
    A name that matches several active tokens is refused (revoke by id)."""
    if ref.isascii() and ref.isdigit():
        rows = session.execute(text("SELECT id, name, revoked_at FROM api_tokens "
                                    "WHERE id = :id FOR UPDATE"),
                               {"id": int(ref) if len(ref) < 10 else -1}).all()
    elif ref.isprintable():  # as names are; a NUL would not even reach PostgreSQL
        rows = session.execute(text("SELECT id, name, revoked_at FROM api_tokens "
                                    "WHERE name = :n AND revoked_at IS NULL FOR UPDATE"),
                               {"n": ref}).all()
    else:
        rows = []
    if not rows:
        raise UserError(f"no active token {ref[:80]!r} (see `ugvmap tokens list`)")
    if len(rows) > 1:
        raise UserError(f"{len(rows)} active tokens are named {ref[:80]!r}; revoke one by id "
                        "(see `ugvmap tokens list`)")
    if rows[0].revoked_at is not None:
        raise UserError(f"token {rows[0].id} was already revoked at {rows[0].revoked_at:%F %T}")
    session.execute(text("UPDATE api_tokens SET revoked_at = now() WHERE id = :id"),
                    {"id": rows[0].id})
    return dict(rows[0]._mapping)


def presented_token(authorization: str | None) -> str:
    """The token of an ``Authorization`` header: ``Bearer <token>``, or HTTP Basic with the
    token as the password (any user name). Basic is what QGIS sends from a connection's user
    name and password (its OAPIF provider has no bearer-token field), so a QGIS user pastes
    the token into the password box; the user name is ignored (the token says who it is)."""
    scheme, _, credentials = (authorization or "").partition(" ")
    credentials = credentials.strip()
    if scheme.lower() == "basic" and credentials:
        try:
            decoded = base64.b64decode(credentials, validate=True).decode("utf-8")
        except (binascii.Error, UnicodeDecodeError):
            raise UnauthorizedError("HTTP Basic credentials must be base64 of "
                                    "'user:token'") from None
        credentials = decoded.partition(":")[2]
    elif scheme.lower() != "bearer":
        credentials = ""
    if not credentials:
        raise UnauthorizedError("an 'Authorization: Bearer <token>' header (or HTTP Basic "
                                "with the token as password) is required")
    return credentials


def authenticate(session: Session, authorization: str | None) -> Principal:
    """The principal a token belongs to; 401 with a challenge when it is missing, unknown,
    revoked or expired (read from the database on every request)."""
    token = presented_token(authorization)
    row = session.execute(text(
        "SELECT id, name, role, revoked_at IS NOT NULL AS revoked, "
        "       expires_at IS NOT NULL AND expires_at <= now() AS expired, "
        "       last_used_at IS NULL OR last_used_at < now() - make_interval(secs => :every) "
        "         AS touch "
        "FROM api_tokens WHERE token_hash = :h"),
        {"h": hash_token(token), "every": TOUCH_EVERY_S}).first()
    if row is None:
        raise UnauthorizedError("the token is unknown")
    if row.revoked or row.expired:
        raise UnauthorizedError(f"the token has been {'revoked' if row.revoked else 'expired'}")
    if row.touch:
        _touch(session, row.id)
    return Principal(row.name, row.role)


def _touch(session: Session, token_id: int) -> None:
    """Record the use in its own short transaction (committed even if the request fails, and
    no lock held for the request's duration); the condition makes concurrent touches from
    other workers no-ops."""
    with session.get_bind().engine.connect() as conn:
        conn.execute(text(
            "UPDATE api_tokens SET last_used_at = now() WHERE id = :id AND (last_used_at IS NULL "
            "OR last_used_at < now() - make_interval(secs => :every))"),
            {"id": token_id, "every": TOUCH_EVERY_S})
        conn.commit()
