"""Command-line behaviour shared by every command."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.conftest import REPO, free_port


@pytest.mark.parametrize("args", [["layers", "list"], ["db", "upgrade"],
                                  ["route", "x", "--points", "0,0;1,1"]])
def test_unreachable_database_is_one_line_not_a_traceback(args: list[str]) -> None:
    env = {**os.environ, "DATABASE_URL": f"postgresql://postgres@127.0.0.1:{free_port()}/x"}
    proc = subprocess.run([sys.executable, "-m", "app.cli", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    assert "cannot reach the database" in proc.stderr
    assert "Traceback" not in proc.stderr
