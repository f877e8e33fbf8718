"""Benchmark: road network import and vector tiles, against named baselines in the same run.

- Import: ``ugvmap`` (read + node into a topology + COPY + geography lengths) vs GDAL's
  ``ogr2ogr`` OSM driver loading the same extract's ``lines`` layer into PostGIS (no topology,
  no noding, no attribute mapping: the cheapest way to get OSM roads into PostGIS).
- Tiles: every z16 tile over Helsinki through the ugvmap HTTP app, cold (rendered) and warm
  (cache), vs the bare ``ST_AsMVT`` query over psycopg (what a minimal PostGIS tile server does).

Run: ``.venv/bin/python bench/network_import.py`` (uses DATABASE_URL or the embedded cluster;
creates and drops a throwaway database).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import morecantile
import psycopg
from sqlalchemy.engine import make_url

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.db.session import libpq_dsn
from app.settings import get_settings
from testkit.scratch import scratch_database

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "osm"
EXTRACTS = ("andorra.osm.pbf", "Helsinki.osm.pbf")
REPEATS = 3


def best(fn, repeats: int = REPEATS) -> float:
    """Best of ``repeats`` runs of ``fn``, in seconds: the least disturbed by other load."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def bench_import(url: str) -> None:
    """Time our import of each OSM extract against ogr2ogr's OSM->PostGIS load of the same file."""
    from app.db.session import session_scope
    from ingest.network import import_network

    u = make_url(url)
    pg = (f"PG:host={u.host} port={u.port} user={u.username} dbname={u.database}"
          + (f" password={u.password}" if u.password else ""))
    print(f"{'extract':<18}{'segments':>9}{'ugvmap s':>10}{'ogr2ogr s':>11}{'ratio':>8}")
    for extract in EXTRACTS:
        path = DATA / extract
        summary = {}

        def ours(path: Path = path, summary: dict = summary) -> None:
            with session_scope() as session:
                summary["s"] = import_network(session, path, "bench", replace=True)

        def baseline(path: Path = path) -> None:
            subprocess.run(["ogr2ogr", "-f", "PostgreSQL", pg, str(path), "lines",
                            "-nln", "bench_lines", "-overwrite", "-lco", "SPATIAL_INDEX=GIST"],
                           check=True, capture_output=True)

        t_ours, t_base = best(ours), best(baseline)
        print(f"{extract:<18}{summary['s'].segments:>9}{t_ours:>10.2f}{t_base:>11.2f}"
              f"{t_ours / t_base:>8.2f}")


def bench_tiles(url: str) -> None:
    """Time z16 vector tiles over HTTP (cold and cached) against the bare ST_AsMVT query."""
    from fastapi.testclient import TestClient

    from app.main import create_app
    from app.network.tiles import TILE_SQL

    tms = morecantile.tms.get("WebMercatorQuad")
    tiles = list(tms.tiles(24.935, 60.164, 24.953, 60.179, [16]))
    with psycopg.connect(libpq_dsn(url)) as conn:
        network_id = conn.execute("SELECT id FROM networks WHERE name = 'bench'").fetchone()[0]
        raw_sql = TILE_SQL.replace(":tolerance", "0").replace(":network_id", "%(n)s")
        for name in ("z", "x", "y"):
            raw_sql = raw_sql.replace(f":{name}", f"%({name})s")

        def raw() -> None:
            for t in tiles:
                conn.execute(raw_sql, {"z": t.z, "x": t.x, "y": t.y, "n": network_id}).fetchone()

        t_raw = best(raw)
    with TestClient(create_app()) as client:
        def http(expect: str) -> None:
            for t in tiles:
                r = client.get(f"/networks/bench/tiles/{t.z}/{t.x}/{t.y}.mvt")
                assert r.status_code == 200 and r.headers["x-tile-cache"] == expect

        client.get(f"/networks/bench/tiles/{tiles[0].z}/{tiles[0].x}/{tiles[0].y}.mvt")
        time.sleep(0.5)
        start = time.perf_counter()
        http_cold = [t for t in tiles if t != tiles[0]]
        for t in http_cold:
            client.get(f"/networks/bench/tiles/{t.z}/{t.x}/{t.y}.mvt")
        t_cold = (time.perf_counter() - start) * len(tiles) / len(http_cold)
        t_warm = best(lambda: http("hit"))
    n = len(tiles)
    print(f"\n{n} z16 tiles over Helsinki (ms per tile)")
    print(f"  bare ST_AsMVT over psycopg (baseline): {t_raw / n * 1000:7.2f}")
    print(f"  ugvmap HTTP, cold (render + cache):    {t_cold / n * 1000:7.2f}"
          f"  ratio {t_cold / t_raw:.2f}")
    print(f"  ugvmap HTTP, warm (cache hit):         {t_warm / n * 1000:7.2f}"
          f"  ratio {t_warm / t_raw:.2f}")


def main() -> None:
    """Run both benchmarks on a scratch database."""
    with scratch_database("ugvmap_bench") as url:
        os.environ["DATABASE_URL"] = url
        get_settings.cache_clear()
        bench_import(url)
        bench_tiles(url)

if __name__ == "__main__":
    main()
