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
    proc = subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    assert "cannot reach the database" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_layers_import_downwards_only() -> None:
    """``cli`` sits on top of ``ingest``, which sits on ``app``: the web app never imports the
    batch jobs or the command line, and the jobs never import the command line."""
    import ast

    forbidden = {"app": ("ingest", "cli"), "ingest": ("cli",)}
    offenders = []
    for package, banned in forbidden.items():
        for path in (REPO / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                         else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
                offenders += [f"{path.relative_to(REPO)}: {n}" for n in names
                              if n.split(".")[0] in banned]
    assert offenders == []
