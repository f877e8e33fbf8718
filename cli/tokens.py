"""``ugvmap tokens``: the API tokens' lifecycle (create, list, revoke).

Registered in :mod:`cli.main`. A token's secret is printed once by ``create`` and never
stored; ``list`` shows everything else. Revocation and expiry hold at once in every server
worker (see :mod:`app.network.tokens`).
"""

from __future__ import annotations

import click


@click.group("tokens")
def tokens() -> None:
    """API tokens for reading (when a read role is set) and editing (stored hashed)."""


@tokens.command("create")
@click.option("--role", type=click.Choice(["viewer", "editor", "admin"]), required=True)
@click.option("--name", required=True, help="Who or what uses the token (shown in history).")
@click.option("--expires", default=None, metavar="DURATION",
              help="Lifetime, e.g. 30d, 12h, 2w (default: until revoked).")
def tokens_create(role: str, name: str, expires: str | None) -> None:
    """Create a token and print it once; only its hash is stored."""
    from app.db.session import session_scope
    from app.network.tokens import create_token, parse_duration

    lifetime = parse_duration(expires) if expires else None
    with session_scope() as session:
        token = create_token(session, name, role, lifetime)
    click.echo(token)


def _when(value: object) -> str:
    return "-" if value is None else f"{value:%Y-%m-%d %H:%M}"


@tokens.command("list")
def tokens_list() -> None:
    """Every token: id, name, role, state, created, last used (to the minute), expiry."""
    from app.db.session import session_scope
    from app.network.tokens import list_tokens

    with session_scope() as session:
        rows = list_tokens(session)
    click.echo(f"{'id':>5}  {'role':<6}  {'state':<7}  {'created':<16}  {'last used':<16}  "
               f"{'expires':<16}  name")
    for r in rows:
        click.echo(f"{r['id']:>5}  {r['role']:<6}  {r['state']:<7}  {_when(r['created_at']):<16}"
                   f"  {_when(r['last_used_at']):<16}  {_when(r['expires_at']):<16}  "
                   f"{r['name']}")


@tokens.command("revoke")
@click.argument("token")
def tokens_revoke(token: str) -> None:
    """Revoke TOKEN (its id, or its name when one active token has it): refused at once."""
    from app.db.session import session_scope
    from app.network.tokens import revoke_token

    with session_scope() as session:
        row = revoke_token(session, token)
    click.echo(f"revoked token {row['id']} ({row['name']})")
