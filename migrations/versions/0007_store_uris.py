"""Raster store references become relative to the store.

``raster_sources.uri`` and ``layers.overview_uri`` held absolute paths of the machine that
ingested them, so a backup restored elsewhere (another host, another store directory) pointed
at files that are not there. Paths under the current store (``UGVMAP_RASTER_STORE``, or
``<data dir>/rasters``) become ``<layer>/<file>.tif``; the code joins them to the configured
store when it reads them (``app.tiles.store.resolve``). References outside the store (or GDAL
URIs) stay absolute and keep working.

Revision ID: 0007_store_uris
Revises: 0006_tokens
Create Date: 2026-11-23
"""

import sqlalchemy as sa
from alembic import op

from app.tiles.store import store_root

revision = "0007_store_uris"
down_revision = "0006_tokens"
branch_labels = None
depends_on = None

COLUMNS = (("raster_sources", "uri"), ("layers", "overview_uri"))


def upgrade() -> None:
    prefix = store_root() + "/"
    for table, column in COLUMNS:
        op.execute(sa.text(
            f"UPDATE {table} SET {column} = substr({column}, length(:prefix) + 1) "
            f"WHERE starts_with({column}, :prefix)").bindparams(prefix=prefix))


def downgrade() -> None:
    prefix = store_root() + "/"
    for table, column in COLUMNS:
        op.execute(sa.text(
            f"UPDATE {table} SET {column} = :prefix || {column} "
            f"WHERE {column} NOT LIKE '/%' AND {column} NOT LIKE '%://%'"
        ).bindparams(prefix=prefix))
