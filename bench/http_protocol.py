"""What respelling header names costs: ours against uvicorn's httptools and h11 protocols.

httptools writes every response header name lower-cased and QGIS 3.34 finds ``Allow`` and
``Location`` only in their usual case, so ``ugvmap serve`` runs httptools through
``app.api.wire.ServiceHttpProtocol``, which respells each response's head; until 2026-11
it ran uvicorn's pure-Python h11 implementation, which writes names as given. This measures
the three, one server at a time, the same app and database, ``wrk -t1 -c8`` for
``--duration`` seconds per URL::

    .venv/bin/python bench/http_protocol.py [--duration 10] [--workers 1]

URLs: ``/healthz`` (the HTTP layer alone), one vector tile (cached after the first request:
mostly HTTP work, 2 KB) and a page of 100 features (database and JSON work). Prints requests
per second per protocol and the ratio of each to plain httptools; the machine is shared, so
ratios from one run are what to compare.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from app.db.session import get_engine  # noqa: E402
from app.settings import get_settings  # noqa: E402
from testkit.network_helpers import grid_network  # noqa: E402
from testkit.scratch import scratch_database  # noqa: E402
from testkit.server import free_port  # noqa: E402

SERVE = """
import sys, uvicorn
from app.api.wire import ServiceHttpProtocol
http = ServiceHttpProtocol if sys.argv[2] == "ours" else sys.argv[2]
uvicorn.run("app.main:create_app", factory=True, host="127.0.0.1", port=int(sys.argv[1]),
            workers=int(sys.argv[3]), http=http, log_level="warning", access_log=False)
"""


PROTOCOLS = ("ours", "httptools", "h11")


def requests_per_s(url: str, duration: int) -> float:
    """wrk's requests per second on one URL."""
    out = subprocess.run(["wrk", "-t1", "-c8", f"-d{duration}s", url], capture_output=True,
                         text=True, check=True).stdout
    match = re.search(r"Requests/sec:\s+([0-9.]+)", out)
    assert match, out
    return float(match[1])


def serve(protocol: str, workers: int, env: dict[str, str]) -> tuple[subprocess.Popen, str]:
    """The app under uvicorn with ``protocol`` (``ours``, ``httptools`` or ``h11``), once it
    answers."""
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-c", SERVE, str(port), protocol, str(workers)],
                            cwd=REPO, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    for _ in range(300):
        try:
            httpx.get(f"{base}/healthz", timeout=1)
            return proc, base
        except httpx.TransportError:
            time.sleep(0.1)
    proc.kill()
    raise RuntimeError(f"{protocol} server did not start")


def main() -> None:
    """Measure the three protocols on the three URLs and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=int, default=10)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    with scratch_database("ugvmap_bench_http") as url:
        os.environ["DATABASE_URL"] = url
        get_settings.cache_clear()
        get_engine.cache_clear()
        net = grid_network().network
        env = {**os.environ, "DATABASE_URL": url, "UGVMAP_LOG_LEVEL": "WARNING"}
        paths = {"healthz": "/healthz",
                 "MVT tile z16": f"/networks/{net}/tiles/16/34588/22337.mvt",
                 "100 features": f"/collections/{net}-segments/items?limit=100"}
        results: dict[str, dict[str, float]] = {}
        for protocol in PROTOCOLS:
            proc, base = serve(protocol, args.workers, env)
            try:
                for name, path in paths.items():
                    httpx.get(base + path).raise_for_status()  # warm (tile cache, pool)
                    results.setdefault(name, {})[protocol] = requests_per_s(base + path,
                                                                            args.duration)
            finally:
                proc.terminate()
                proc.wait(timeout=10)
    print(f"{'URL':<14}" + "".join(f"{p + ' req/s':>17}" for p in PROTOCOLS)
          + f"{'ours/httptools':>16}{'h11/httptools':>15}")
    for name, by in results.items():
        print(f"{name:<14}" + "".join(f"{by[p]:>17.0f}" for p in PROTOCOLS)
              + f"{by['ours'] / by['httptools']:>16.2f}{by['h11'] / by['httptools']:>15.2f}")


if __name__ == "__main__":
    main()
