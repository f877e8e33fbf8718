"""Which package may import which, checked two ways: by reading every module's imports, and by
importing the modules for real.

The rule (docs/architecture.md): ``cli`` sits on ``ingest``, which sits on ``app``; inside
``app`` the HTTP layer (``app.main``, ``app.api``, every ``*router`` module) sits on the core.
The batch jobs and the command line stand on the core only: nothing they import when loaded
may import the web framework. A command may still import it *inside* a function, as
``ugvmap serve`` does with uvicorn, so only imports run at load time count.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

WEB_FRAMEWORK = ("fastapi", "starlette", "uvicorn")


def module_name(root: Path, path: Path) -> str:
    """``root/app/tiles/router.py`` -> ``app.tiles.router``; a package's ``__init__`` is the
    package."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _load_time_imports(tree: ast.Module, module: str, is_package: bool) -> list[str]:
    """Every name imported when the module is loaded: not inside a function, not under
    ``if TYPE_CHECKING``. ``from a import b`` gives ``a`` and ``a.b`` (b may be a module)."""
    found: list[str] = []

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                visit(node.orelse)
                continue
            if isinstance(node, ast.Import):
                found.extend(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    package = module.split(".")[:None if is_package else -1]
                    package = package[:len(package) - node.level + 1]
                    base = ".".join([*package, *([base] if base else [])])
                found.extend([base, *(f"{base}.{alias.name}" for alias in node.names)])
            for field in ("body", "orelse", "finalbody", "handlers"):
                visit([n for n in getattr(node, field, []) if isinstance(n, ast.stmt)]
                      if field != "handlers" else
                      [s for h in getattr(node, field, []) for s in h.body])

    visit(tree.body)
    return found


def import_graph(root: Path, packages: tuple[str, ...]) -> dict[str, set[str]]:
    """Module -> what loading it imports: our modules by name, anything else by its top-level
    package (``fastapi.responses`` -> ``fastapi``). Importing ``a.b`` also loads ``a``."""
    trees = {module_name(root, path): (ast.parse(path.read_text()), path.name == "__init__.py")
             for package in packages for path in (root / package).rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for module, (tree, is_package) in trees.items():
        names = _load_time_imports(tree, module, is_package)
        names += [module.rpartition(".")[0]] if "." in module else []
        deps: set[str] = set()
        for name in names:
            parts = name.split(".")
            for i in range(1, len(parts) + 1):
                prefix = ".".join(parts[:i])
                if prefix in trees:
                    deps.add(prefix)
                elif parts[0] not in packages:
                    deps.add(parts[0])
        graph[module] = deps - {module}
    return graph


def chains_to(root: Path, packages: tuple[str, ...], starts: tuple[str, ...],
              banned: tuple[str, ...] = WEB_FRAMEWORK) -> list[str]:
    """For each module of ``starts`` whose loading reaches a ``banned`` package, one shortest
    import chain to it, e.g. ``ingest.demo -> app.tiles.catalog -> fastapi``."""
    graph = import_graph(root, packages)
    chains = []
    for start in sorted(m for m in graph if m.split(".")[0] in starts):
        came_from: dict[str, str | None] = {start: None}
        queue = [start]
        while queue:
            module = queue.pop(0)
            if module in banned:
                chain = [module]
                while (previous := came_from[chain[-1]]) is not None:
                    chain.append(previous)
                chains.append(" -> ".join(reversed(chain)))
                break
            for dep in sorted(graph.get(module, ())):
                if dep not in came_from:
                    came_from[dep] = module
                    queue.append(dep)
    return chains


def web_modules_loaded(root: Path, starts: tuple[str, ...],
                       banned: tuple[str, ...] = WEB_FRAMEWORK) -> list[str]:
    """Import every module of the ``starts`` packages in a fresh interpreter (``root`` first on
    its path) and return the ``banned`` packages that ended up loaded."""
    script = (
        "import importlib, pkgutil, sys\n"
        f"for top in {starts!r}:\n"
        "    package = importlib.import_module(top)\n"
        "    for info in pkgutil.walk_packages(package.__path__, top + '.'):\n"
        "        if not info.name.endswith('.__main__'):\n"
        "            importlib.import_module(info.name)\n"
        f"print(' '.join(sorted({{m.split('.')[0] for m in sys.modules}} & set({banned!r}))))\n")
    proc = subprocess.run([sys.executable, "-c", script], cwd=root, capture_output=True,
                          text=True, timeout=600, env={**os.environ, "PYTHONPATH": str(root)})
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.split()


def deferred_web_imports(root: Path, packages: tuple[str, ...]) -> list[str]:
    """Every import of the web framework or of the HTTP layer made inside a function of the
    ``packages``, as ``module.function: imported``: the exceptions the load-time rule allows,
    listed so that a new one is a decision, not an accident."""
    found = set()
    for package in packages:
        for path in (root / package).rglob("*.py"):
            module = module_name(root, path)
            for func in ast.walk(ast.parse(path.read_text())):
                if not isinstance(func, ast.FunctionDef | ast.AsyncFunctionDef):
                    continue
                for node in ast.walk(func):
                    names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                             else [node.module or ""] if isinstance(node, ast.ImportFrom)
                             else [])
                    found.update(f"{module}.{func.name}: {name}" for name in names
                                 if name.split(".")[0] in WEB_FRAMEWORK or is_http_module(name))
    return sorted(found)


def is_http_module(module: str) -> bool:
    """The HTTP layer, by name: the app, ``app.api``, and each capability's ``*router``."""
    return (module == "app.main" or module.startswith("app.api.") or module == "app.api"
            or module.rpartition(".")[2].endswith("router"))
