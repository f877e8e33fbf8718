"""Commands that behave like their peers (issue 22): ``network list`` as ``layers list``,
``layers delete`` asks like ``network delete``, a file already in a layer is refused unless
``--replace`` (which replaces it), errors name the real flag, and modules run with
``python -m`` do what they say or print their usage."""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import get_engine
from cli.main import main
from testkit.network_helpers import grid_network
from testkit.raster_synth import synthetic_utm
from tests.conftest import REPO


def run(*args: str, stdin: str | None = None) -> tuple[int, str]:
    result = CliRunner().invoke(main, list(args), input=stdin)
    return result.exit_code, result.output


def _sources(slug: str) -> list[tuple[str, str]]:
    with get_engine().connect() as conn:
        return [tuple(r) for r in conn.execute(text(
            "SELECT s.name, s.uri FROM raster_sources s JOIN layers l ON l.id = s.layer_id "
            "WHERE l.slug = :s ORDER BY s.id"), {"s": slug})]


def test_network_list_lists_networks_like_layers_list(database_url: str) -> None:
    net = grid_network()
    code, out = run("network", "list")
    assert code == 0
    line = next(li for li in out.splitlines() if li.startswith(net.network + "\t"))
    assert "\t12 segments\t9 nodes\tv" in line


def test_layers_delete_asks_unless_yes(database_url: str, tmp_path: Path) -> None:
    path, _ = synthetic_utm(tmp_path / "d.tif", width=64, height=64)
    slug = f"del-{uuid.uuid4().hex[:8]}"
    assert run("ingest", "raster", str(path), "--layer", slug)[0] == 0
    files = [f for f in Path(os.environ["UGVMAP_RASTER_STORE"], slug).iterdir()]
    code, out = run("layers", "delete", slug, stdin="n\n")
    assert code == 1 and "Delete raster layer" in out and "Aborted" in out
    assert len(_sources(slug)) == 1 and all(f.exists() for f in files)
    assert run("layers", "delete", slug, stdin="y\n")[0] == 0
    assert _sources(slug) == [] and not any(f.exists() for f in files)
    code, out = run("layers", "delete", slug, "--yes")
    assert code == 1 and f"no raster layer {slug!r}" in out


def test_a_file_already_in_the_layer_is_refused_unless_replace(database_url: str,
                                                                 tmp_path: Path) -> None:
    """The same file (even under another name) stacked a duplicate source; now it is refused
    naming --replace, which swaps the old source (and its COG) for the new one."""
    path, _ = synthetic_utm(tmp_path / "zone.tif", width=64, height=64)
    copy = tmp_path / "copy.tif"
    copy.write_bytes(path.read_bytes())
    slug = f"re-{uuid.uuid4().hex[:8]}"
    assert run("ingest", "raster", str(path), "--layer", slug)[0] == 0
    [(_, first_uri)] = _sources(slug)
    for again in (path, copy):
        code, out = run("ingest", "raster", str(again), "--layer", slug)
        assert code == 1 and "already has this file as source" in out and "--replace" in out
        assert "use replace" not in out
    assert len(_sources(slug)) == 1
    code, out = run("ingest", "raster", str(path), str(copy), "--layer", f"{slug}-b")
    assert code == 1 and "given more than once" in out
    code, out = run("ingest", "raster", str(path), "--layer", slug, "--replace")
    assert code == 0, out
    [(name, uri)] = _sources(slug)
    assert name == "zone.tif" and uri != first_uri
    store = Path(os.environ["UGVMAP_RASTER_STORE"])
    assert not (store / first_uri).exists() and (store / uri).exists()
    # A network's --replace is named the same way.
    net = grid_network()
    geojson = tmp_path / "n.geojson"
    geojson.write_text('{"type": "FeatureCollection", "features": [{"type": "Feature", '
                       '"geometry": {"type": "LineString", "coordinates": [[1, 1], [1.001, 1]]},'
                       ' "properties": {}}]}')
    code, out = run("ingest", "network", str(geojson), "--network", net.network)
    assert code == 1 and "--replace" in out


def _main_modules() -> list[str]:
    """Every module under app/, ingest/ and testkit/ with a ``__main__`` block."""
    found = []
    for folder in ("app", "ingest", "testkit"):
        for path in sorted((REPO / folder).rglob("*.py")):
            if 'if __name__ == "__main__":' in path.read_text():
                found.append(".".join(path.relative_to(REPO).with_suffix("").parts))
    return found


@pytest.mark.parametrize("module", ["ingest.ipm.synthetic", *_main_modules()])
def test_python_m_modules_print_their_usage(module: str) -> None:
    """``python -m ingest.ipm.synthetic`` exited silently, doing nothing."""
    proc = subprocess.run([sys.executable, "-m", module, "--help"], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "usage:" in proc.stdout.lower(), module
    bare = subprocess.run([sys.executable, "-m", module], cwd=REPO, capture_output=True,
                          text=True, timeout=120)
    assert bare.returncode != 0 and "usage:" in bare.stderr.lower(), module


def test_the_synthetic_drive_is_written(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "ingest.ipm.synthetic", str(tmp_path / "d"),
                           "--frames", "2"], cwd=REPO, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == \
        ["calib.json", "frames", "mask.png", "poses.csv"]
    assert len(list((tmp_path / "d" / "frames").glob("*.jpg"))) == 2
