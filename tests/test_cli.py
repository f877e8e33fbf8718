"""Command-line behaviour shared by every command."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests import layering
from tests.conftest import REPO, free_port

PACKAGES = ("app", "ingest", "cli")


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


def test_ingest_and_cli_never_import_the_http_layer() -> None:
    """The batch jobs and the command line stand on the HTTP-free core: loading any of their
    modules loads no web framework (fastapi, starlette, uvicorn), so no HTTP module either.
    Checked by reading every module's load-time imports (which names the chain at fault) and
    by importing every ``ingest``/``cli`` module in a fresh interpreter. The one command that
    runs the web stack, ``ugvmap serve``, imports it inside its function, when it runs."""
    assert layering.chains_to(REPO, PACKAGES, ("ingest", "cli")) == []
    assert layering.web_modules_loaded(REPO, ("ingest", "cli")) == []
    assert layering.deferred_web_imports(REPO, ("ingest", "cli")) == [
        "cli.demo.serve: app.api.wire", "cli.demo.serve: uvicorn"]


def test_only_http_modules_import_the_web_framework() -> None:
    """Inside ``app`` the core (db, store, grid, settings, errors, network model and edits,
    routing engine, jobs...) imports no web framework; only the HTTP layer does: ``app.main``,
    ``app.api`` and each capability's ``router``/``*_router`` module, beside its logic."""
    graph = layering.import_graph(REPO, PACKAGES)
    offenders = sorted(module for module, deps in graph.items()
                       if deps & set(layering.WEB_FRAMEWORK)
                       and not layering.is_http_module(module))
    assert offenders == []


def test_layering_check_catches_a_violation(tmp_path: Path) -> None:
    """The two checks above fail on a deliberate violation: a job package whose module-level
    import reaches, through a core module, one that imports fastapi. An import inside a
    function (``ugvmap serve``'s uvicorn) is allowed and not reported."""
    files = {
        "job/__init__.py": "",
        "job/run.py": "from core import model\n\n\ndef serve():\n    import uvicorn\n",
        "core/__init__.py": "",
        "core/model.py": "from .web import app\n",
        "core/web.py": "from fastapi import FastAPI\n\napp = FastAPI()\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text(text)
    assert layering.chains_to(tmp_path, ("job", "core"), ("job",)) == [
        "job.run -> core.model -> core.web -> fastapi"]
    assert "fastapi" in layering.web_modules_loaded(tmp_path, ("job",))
    assert layering.deferred_web_imports(tmp_path, ("job",)) == ["job.run.serve: uvicorn"]
    (tmp_path / "core/model.py").write_text("def app():\n    from .web import app\n")
    assert layering.chains_to(tmp_path, ("job", "core"), ("job",)) == []
    assert layering.web_modules_loaded(tmp_path, ("job",)) == []


@pytest.mark.parametrize("args", [["layers", "list"], ["network", "list"]])
def test_a_database_without_the_schema_is_one_clear_line(args: list[str]) -> None:
    """A reachable database nobody has upgraded (a new cluster, another DATABASE_URL) says
    what to run instead of printing SQLAlchemy's traceback (it did, from any folder)."""
    from testkit.scratch import scratch_database

    with scratch_database("ugvmap_cli_empty", migrated=False) as url:
        proc = subprocess.run([sys.executable, "-m", "cli", *args], cwd=REPO, text=True,
                              capture_output=True, env={**os.environ, "DATABASE_URL": url})
    assert proc.returncode == 1, proc.stderr
    assert "run `ugvmap db upgrade`" in proc.stderr and "Traceback" not in proc.stderr
