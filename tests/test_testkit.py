"""Scaffolding stays out of the product: ``app``, ``ingest`` and ``cli`` never import the test
kit (or the tests), and the benchmarks share helpers with the tests through ``testkit``, never
through ``tests``. (A rule of the same kind as the layering test in ``tests/test_cli.py``; the
two could become one table.)"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

from tests.conftest import REPO

SCAFFOLDING = ("testkit", "tests", "bench")
BANNED = {"app": SCAFFOLDING, "ingest": SCAFFOLDING, "cli": SCAFFOLDING,
          "testkit": ("tests", "bench"), "bench": ("tests",)}


def imported_modules(path: Path) -> Iterator[str]:
    """Every module ``path`` imports, at any depth (imports inside functions included)."""
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield node.module


def test_scaffolding_is_imported_only_by_tests_and_benchmarks() -> None:
    offenders = [f"{path.relative_to(REPO)}: {name}"
                 for package, banned in BANNED.items()
                 for path in (REPO / package).rglob("*.py")
                 for name in imported_modules(path) if name.split(".")[0] in banned]
    assert offenders == []
