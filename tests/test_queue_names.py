"""The queue names its code by strings (a job kind's runner, a deferred task): each must
resolve to real code, or a typo would only show in a worker, as a failed job."""

from __future__ import annotations

import ast
import importlib
import inspect
import subprocess
import sys

import pytest

from app.jobs.kinds import JOB_KINDS
from ingest.queue.tasks import resolve_runner
from tests.conftest import REPO


@pytest.mark.parametrize("kind", JOB_KINDS)
def test_every_job_kind_names_a_runner_taking_its_parameters(kind: str) -> None:
    runner = resolve_runner(JOB_KINDS[kind].runner)
    job_id, params = inspect.signature(runner, eval_str=True).parameters.values()
    assert (job_id.annotation, params.annotation) == (int, JOB_KINDS[kind].params)


@pytest.mark.parametrize("name", ["ingest.queue.runners:ingest_roadz",
                                  "ingest.queue.runnerz:ingest_roads"])
def test_a_misspelt_runner_is_refused(name: str) -> None:
    with pytest.raises((AttributeError, ImportError)):
        resolve_runner(name)


def deferred_task_names() -> dict[str, str]:
    """Every task name the code defers, found as the task argument of each ``defer(...)``
    call in app/ and ingest/ and read from the calling module: {where: name}."""
    names = {}
    for package in ("app", "ingest"):
        for path in (REPO / package).rglob("*.py"):
            module = ".".join(path.relative_to(REPO).with_suffix("").parts)
            for node in ast.walk(ast.parse(path.read_text())):
                if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                        and node.func.id == "defer" and len(node.args) >= 2):
                    assert isinstance(node.args[1], ast.Name), f"{module}: name the task once"
                    value = getattr(importlib.import_module(module), node.args[1].id)
                    names[f"{module}:{node.lineno}"] = value
    return names


def worker_task_names() -> set[str]:
    """The tasks ``ugvmap worker`` registers, asked of a fresh process: registering renames
    the blueprint's tasks in place, so this process's blueprint depends on what ran before."""
    proc = subprocess.run(
        [sys.executable, "-c", "from ingest.queue.worker import make_worker_app\n"
                               "print('\\n'.join(make_worker_app().tasks))"],
        cwd=REPO, capture_output=True, text=True, timeout=120, check=True)
    return set(proc.stdout.split())


def test_every_deferred_task_is_registered_with_the_worker() -> None:
    registered = worker_task_names()
    deferred = deferred_task_names()
    assert len(deferred) >= 3  # run_job, raster_part, raster_finish
    assert {where: name for where, name in deferred.items() if name not in registered} == {}
