"""The embedded cluster manager: clear errors instead of silently using someone else's server."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest
from sqlalchemy.engine import make_url

from cli.ops import embedded


def test_port_taken_by_another_server_is_a_clear_error(database_url: str) -> None:
    busy_port = make_url(database_url).port or 5432
    root = Path(tempfile.mkdtemp(prefix="ugvmap-pg-"))
    os.chmod(root, 0o755)
    cluster = embedded.Cluster(root / "postgres", busy_port, "ugvmap")
    try:
        with pytest.raises(embedded.EmbeddedDbError, match="taken by another PostgreSQL"):
            embedded.start(cluster)
        assert not embedded.is_running(cluster)
        assert embedded.status(cluster).startswith("stopped")
    finally:
        shutil.rmtree(root, ignore_errors=True)
