"""Token lifecycle: an optional expiry per API token.

``revoked_at`` and ``last_used_at`` exist since 0001; ``ugvmap tokens revoke`` now sets the
first and authentication (throttled) the second. A token past ``expires_at`` is refused by the
same query that finds it, so expiry, like revocation, holds at once in every worker: no worker
caches whether a token is valid.

Revision ID: 0006_tokens
Revises: 0005_queue
Create Date: 2026-11-23
"""

import sqlalchemy as sa
from alembic import op

revision = "0006_tokens"
down_revision = "0005_queue"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("api_tokens", sa.Column("expires_at", sa.DateTime(timezone=True)))


def downgrade() -> None:
    op.drop_column("api_tokens", "expires_at")
