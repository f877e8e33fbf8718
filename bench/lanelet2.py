"""Benchmark: the Lanelet2 export, against the plain OSM export of the same network in the
same run (the baseline: the cheapest way to write the network out as OSM XML/PBF).

Each export runs as its own ``ugvmap export network`` process (what a user runs), measured
for wall time and peak RSS; the Lanelet2 figure is lanelets written per second.

Run: ``.venv/bin/python bench/lanelet2.py [--country [--side 810]]`` (uses DATABASE_URL or the
embedded cluster; creates and drops a throwaway database). ``--country`` adds the 1M-segment
synthetic country of ``bench/routing.py`` (generated once into .data/bench, imported ~2 min;
its map is several GB: it is written to .data/bench and deleted after).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psycopg

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from app.db.session import libpq_dsn, session_scope  # noqa: E402
from app.settings import get_settings  # noqa: E402
from testkit.scratch import scratch_database  # noqa: E402

OSM = REPO.parent / "shared" / "data" / "osm" / "andorra.osm.pbf"
UGVMAP = str(REPO / ".venv" / "bin" / "ugvmap")
# Runs a command and prints its peak RSS (KiB): the child's own, not this process's.
MEASURE = ("import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
           "print('PEAK', resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); "
           "sys.exit(r.returncode)")


def measured(args: list[str]) -> tuple[float, float, str]:
    """(seconds, peak RSS MiB, stdout) of one ugvmap command in its own process."""
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", MEASURE, UGVMAP, *args], check=True,
                          capture_output=True, text=True, env=os.environ.copy())
    took = time.perf_counter() - start
    peak = int(re.search(r"PEAK (\d+)", done.stdout)[1]) / 1024  # type: ignore[index]
    return took, peak, done.stdout


def bench_network(name: str, folder: Path) -> None:
    """Lanelet2 vs OSM export of network ``name``; prints one table row each."""
    osm_out, map_out = folder / f"{name}.osm.pbf", folder / f"{name}.lanelet2.osm"
    base_s, base_mib, _ = measured(["export", "network", name, "--format", "osm", "--out",
                                    str(osm_out)])
    ours_s, ours_mib, out = measured(["export", "network", name, "--format", "lanelet2",
                                      "--out", str(map_out)])
    found = re.search(r"(\d+) lanelets \((\d+) in junctions\) for (\d+) segments", out)
    assert found, out
    lanelets, junction, segments = (int(g) for g in found.groups())
    not_drawn = re.search(r"(\d+) junction movements not drawn", out)
    size_mb = map_out.stat().st_size / 1e6
    print(f"{name:<10}{segments:>10,}{lanelets:>11,}{ours_s:>9.1f}{lanelets / ours_s:>12,.0f}"
          f"{ours_mib:>9.0f}{size_mb:>9.0f}{base_s:>9.1f}{base_mib:>9.0f}"
          f"{ours_s / base_s:>8.1f}")
    print(f"{'':<10}({junction:,} junction lanelets, "
          f"{not_drawn[1] if not_drawn else 0} movements not drawable)")
    map_out.unlink()
    osm_out.unlink()


def main() -> None:
    """Export Andorra (and the country) both ways and print the figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--country", action="store_true", help="add the 1M-segment country")
    ap.add_argument("--side", type=int, default=810, help="country side (810 -> 1.02M segments)")
    args = ap.parse_args()
    with scratch_database("ugvmap_bench") as url, \
            psycopg.connect(libpq_dsn(url), autocommit=True) as conn:
        os.environ["DATABASE_URL"] = url
        get_settings.cache_clear()
        from ingest.network import import_network

        with session_scope(url) as session:
            import_network(session, OSM, "andorra")
        if args.country:
            from bench.routing import country

            country(argparse.Namespace(side=args.side), url, conn)
        print(f"{'network':<10}{'segments':>10}{'lanelets':>11}{'l2 s':>9}{'lanelets/s':>12}"
              f"{'l2 MiB':>9}{'l2 MB':>9}{'osm s':>9}{'osm MiB':>9}{'ratio':>8}")
        big = REPO / ".data" / "bench"
        big.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix="ugvmap-lanelet2-", dir=big) as folder:
            for name in ("andorra", "country") if args.country else ("andorra",):
                bench_network(name, Path(folder))


if __name__ == "__main__":
    main()
