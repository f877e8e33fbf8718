"""GDAL's OAPIF driver copying a network from our OGC API: HTTP requests, seconds and stderr
errors per copy, against Debian's ogr2ogr with its default page size as the baseline.

    .venv/bin/python bench/ogc_clients.py

Imports ``../shared/data/osm/andorra.osm.pbf`` (2,794 segments) into a throwaway database,
serves it, and copies ``andorra-segments`` to GeoJSON with Debian's ``ogr2ogr`` (GDAL 3.6,
which pages by 10 unless told ``-oo PAGE_SIZE``) and with pyogrio's bundled GDAL (3.8+ reads
the ``limit`` maximum and default from the API document), in full and with
``-where "road_class = 'primary'"``. Requests are counted from GDAL's own debug log.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from app.db.session import session_scope  # noqa: E402
from app.settings import get_settings  # noqa: E402
from testkit.scratch import scratch_database  # noqa: E402
from testkit.server import running_server  # noqa: E402

OSM = REPO.parent / "shared" / "data" / "osm" / "andorra.osm.pbf"
LAYER = "andorra-segments"
WHERE = "road_class = 'primary'"
PYOGRIO = """
import sys
import pyogrio, pyogrio.raw as raw
meta, fids, geom, fields = raw.read(sys.argv[1], layer=sys.argv[2], where=sys.argv[3] or None)
print(len(geom), pyogrio.__gdal_version_string__)
"""


def ogr2ogr(url: str, where: str | None, options: list[str]) -> list[str]:
    """Debian's ogr2ogr copying the layer to a temporary GeoJSON file."""
    out = Path(tempfile.mkdtemp()) / "copy.geojson"
    return ["ogr2ogr", "--config", "CPL_DEBUG", "ON", "-f", "GeoJSON", str(out),
            f"OAPIF:{url}", LAYER, *(["-where", where] if where else []), *options]


def pyogrio(url: str, where: str | None) -> list[str]:
    """pyogrio's GDAL reading the layer in full."""
    return [sys.executable, "-c", PYOGRIO, f"OAPIF:{url}", LAYER, where or ""]


def measure(command: list[str]) -> tuple[int, int, float]:
    """(requests, stderr error lines, seconds) of one copy."""
    start = time.perf_counter()
    run = subprocess.run(command, capture_output=True, text=True, timeout=900,
                         env={**os.environ, "CPL_DEBUG": "ON"})
    seconds = time.perf_counter() - start
    if run.returncode:
        raise RuntimeError(run.stderr[-2000:])
    lines = run.stderr.splitlines()
    return (sum("HTTP: Fetch(" in line for line in lines),
            sum(line.startswith("ERROR") for line in lines), seconds)


def main() -> None:
    """Copy Andorra's segments every way and print the table."""
    if not OSM.is_file():
        sys.exit(f"{OSM} not found")
    from ingest.network import import_network

    with scratch_database("ugvmap_bench_ogc") as url:
        os.environ["DATABASE_URL"] = url
        get_settings.cache_clear()
        with session_scope(url) as session:
            import_network(session, OSM, "andorra")
        with running_server({"DATABASE_URL": url, "UGVMAP_LOG_LEVEL": "WARNING"}) as base:
            rows = [
                ("ogr2ogr (GDAL 3.6), default page size", ogr2ogr(base, None, [])),
                ("ogr2ogr (GDAL 3.6), -oo PAGE_SIZE=10000",
                 ogr2ogr(base, None, ["-oo", "PAGE_SIZE=10000"])),
                ("pyogrio (bundled GDAL), API document's limit", pyogrio(base, None)),
                (f"ogr2ogr (GDAL 3.6), -where {WHERE!r}", ogr2ogr(base, WHERE, [])),
                (f"pyogrio (bundled GDAL), where {WHERE!r}", pyogrio(base, WHERE)),
            ]
            results = [(label, *measure(command)) for label, command in rows]
    baseline = results[0][1]
    print(f"{'copy of ' + LAYER:<58} {'requests':>8} {'ratio':>6} {'errors':>6} {'s':>6}")
    for label, requests, errors, seconds in results:
        print(f"{label:<58} {requests:>8} {requests / baseline:>6.3f} {errors:>6} "
              f"{seconds:>6.1f}")


if __name__ == "__main__":
    main()
