"""Raster benchmark: ugvmap vs TiTiler tile throughput, and ugvmap ingest vs GDAL's COG driver.

One command (from the repo root)::

    .venv/bin/python bench/tiles.py [--workers 1] [--duration 15] [--skip-ingest]
                                    [--skip-tiles] [--skip-cache] [--skip-s3]

1. **Tiles.** A real-texture test image (the valid part of the shared ``RGB.byte.tif``,
   mirror-tiled to ``--size`` px, 0.3 m/px, EPSG:32618, as in
   ``shared/research/anchors-measured.md``) is ingested by ugvmap. ugvmap and TiTiler then
   serve *the same COG* with the same number of uvicorn workers, one server at a time, each
   loaded by ``wrk -t1 -c8`` cycling through a shuffled list of distinct tiles (256 px PNG)
   at the native zoom and at native - 3 (overviews). Neither uses a tile cache (ugvmap's is
   switched off with ``UGVMAP_TILE_CACHE_MB=0``). TiTiler runs
   from its own venv, ``bench/.venv-titiler``, created on first use (never a project
   dependency).
2. **Front cache.** The same native-zoom tiles through the shipped nginx front cache
   (``cli/ops/frontcache``, versioned URLs from the TileJSON, every tile fetched once first so all
   are HITs) against the *same* nginx serving those PNGs as static files from disk: same wrk
   connections (``-t1 -c8``, keep-alive), same nginx worker, one after the other.
3. **Object storage.** The test image ingested into a local S3-compatible server (moto's
   standalone server, in this process, over HTTP) and served through GDAL's /vsis3/, against
   the same image on local disk, both with the tile cache off and GDAL's block caches (8 MB)
   and, for S3, the downloaded-range cache (4 MB) far below the working set, so most tiles
   read through to the store. moto is a single Python process: a real S3 or MinIO answers
   faster, so this ratio is a floor.
4. **Ingest.** A 28000 x 7000 RGB mosaic is ingested by ``ugvmap ingest raster`` (validation,
   VRT, COG, footprint, catalogue) and converted by a bare GDAL COG-driver call with the same
   target grid and creation options; wall time and peak RSS of each process.

Ratios are printed from figures measured in the same run (the machine is shared).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import random
import re
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import httpx
import numpy as np
import psycopg
import rasterio
from rasterio.transform import from_origin
from sqlalchemy.engine import make_url

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "bench" / "out"
TITILER_VENV = REPO / "bench" / ".venv-titiler"
SAMPLE = REPO.parent / "shared" / "data" / "orthophotos" / "RGB.byte.tif"
LUA = """
local paths = {}
for line in io.lines(os.getenv("TILE_LIST")) do paths[#paths + 1] = line end
local i = 0
request = function()
  i = i % #paths + 1
  return wrk.format("GET", paths[i])
end
done = function(summary, latency, requests)
  io.write(string.format("RESULT %.2f %.1f %.1f %d %d\\n",
    summary.requests / (summary.duration / 1e6), latency:percentile(50) / 1000,
    latency:percentile(99) / 1000, summary.errors.status + summary.errors.connect
    + summary.errors.read + summary.errors.timeout, summary.requests))
end
"""


def texture(width: int, height: int) -> np.ndarray:
    """The fully valid window of RGB.byte.tif, mirror-tiled to width x height."""
    with rasterio.open(SAMPLE) as ds:
        patch = ds.read(window=((300, 501), (250, 514)))  # 201 x 264 px, no nodata
    reps = (1, -(-height // patch.shape[1]), -(-width // patch.shape[2]))
    flipped = [patch, patch[:, :, ::-1]]
    row = np.concatenate([flipped[i % 2] for i in range(reps[2])], axis=2)
    rows = [row if i % 2 == 0 else row[:, ::-1, :] for i in range(reps[1])]
    return np.concatenate(rows, axis=1)[:, :height, :width]


def write_test_image(path: Path, width: int, height: int) -> Path:
    """A textured RGB GeoTIFF (kept between runs), so tiles compress like real imagery."""
    if path.exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    profile = {"driver": "GTiff", "width": width, "height": height, "count": 3,
               "dtype": "uint8", "crs": "EPSG:32618", "tiled": True, "blockxsize": 512,
               "blockysize": 512, "transform": from_origin(500000, 2710000, 0.3, 0.3)}
    with rasterio.open(path, "w", **profile) as ds:
        step = 2048
        for row in range(0, height, step):
            h = min(step, height - row)
            ds.write(texture(width, h), window=((row, row + h), (0, width)))
    return path


def database() -> str:
    """A throwaway migrated database on DATABASE_URL's server (or the embedded cluster)."""
    from app.db import migrate
    from app.settings import get_settings
    from cli.ops import embedded

    settings = get_settings()
    if settings.embedded:
        embedded.start(embedded.cluster_from(settings))
    base = make_url(settings.database_url)
    name = f"ugvmap_bench_{uuid.uuid4().hex[:8]}"
    embedded.ensure_database(f"host={base.host or '127.0.0.1'} port={base.port or 5432} "
                             f"user={base.username or 'postgres'} dbname=postgres", name)
    url = base.set(database=name).render_as_string(hide_password=False)
    migrate.upgrade(url)
    return url


def drop_database(url: str) -> None:
    """Drop the benchmark database, even with connections still open."""
    u = make_url(url)
    admin = u.set(database="postgres", drivername="postgresql")
    with psycopg.connect(admin.render_as_string(hide_password=False), autocommit=True) as c:
        c.execute(f'DROP DATABASE IF EXISTS "{u.database}" WITH (FORCE)')


def ensure_titiler() -> Path:
    """TiTiler in its own venv (created on first run), so its dependencies never touch ours."""
    python = TITILER_VENV / "bin" / "python"
    if not python.exists():
        print("creating bench/.venv-titiler (titiler.application, uvicorn) ...", flush=True)
        subprocess.run([sys.executable, "-m", "venv", str(TITILER_VENV)], check=True)
        subprocess.run([str(python), "-m", "pip", "install", "-q", "titiler.application>=0.18",
                        "uvicorn>=0.29"], check=True)
    return python


def free_port() -> int:
    """A free local TCP port."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start(cmd: list[str], env: dict[str, str], probe: str) -> subprocess.Popen:
    """Start a server and wait until ``probe`` answers 200 (or fail with its stderr)."""
    proc = subprocess.Popen(cmd, cwd=REPO, env={**os.environ, **env},
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if httpx.get(probe, timeout=2).status_code == 200:
                return proc
        except httpx.TransportError:
            pass
        if proc.poll() is not None:
            raise RuntimeError(f"server failed: {proc.stderr.read().decode()[-2000:]}")
        time.sleep(0.2)
    proc.kill()
    raise RuntimeError(f"server did not answer {probe}")


def stop(proc: subprocess.Popen) -> None:
    """Stop a server, killing it if it does not exit in 10 s."""
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()


def wrk(base: str, paths: list[str], duration: int, workers: int = 1) -> dict[str, float]:
    """Tiles per second and latency from wrk cycling through ``paths``, after a warm-up run."""
    OUT.mkdir(parents=True, exist_ok=True)
    tile_list, script = OUT / "tiles.txt", OUT / "cycle.lua"
    tile_list.write_text("\n".join(paths) + "\n")
    script.write_text(LUA)
    # One uvicorn worker takes all keep-alive connections; several workers need new ones
    # (nginx runs are given workers=1: keep-alive, as browsers do).
    extra = ["-H", "Connection: close"] if workers > 1 else []
    env = {**os.environ, "TILE_LIST": str(tile_list)}
    subprocess.run(["wrk", "-t1", "-c8", "-d3s", "--timeout", "10s", "-s", str(script), *extra,
                    base], env=env, capture_output=True, check=True)  # warm-up
    out = subprocess.run(["wrk", "-t1", "-c8", f"-d{duration}s", "--timeout", "10s", "-s",
                          str(script), *extra, base], env=env, capture_output=True, text=True,
                         check=True).stdout
    rate, p50, p99, errors, count = re.search(r"RESULT (\S+) (\S+) (\S+) (\S+) (\S+)",
                                              out).groups()
    return {"tiles_per_s": float(rate), "p50_ms": float(p50), "p99_ms": float(p99),
            "errors": int(errors), "requests": int(count)}


def tile_paths(cog: Path, zoom: int) -> list[tuple[int, int]]:
    """The tiles of the COG at ``zoom``; interior ones only when there are many."""
    import morecantile

    tms = morecantile.tms.get("WebMercatorQuad")
    with rasterio.open(cog) as ds:
        bounds = rasterio.warp.transform_bounds(ds.crs, "EPSG:4326", *ds.bounds)
    tiles = [(t.x, t.y) for t in tms.tiles(*bounds, zooms=[zoom])]
    # Interior tiles only at native zoom (edges are partly empty and cheaper).
    if len(tiles) > 16:
        xs = sorted({x for x, _ in tiles})
        ys = sorted({y for _, y in tiles})
        tiles = [(x, y) for x, y in tiles if xs[0] < x < xs[-1] and ys[0] < y < ys[-1]]
    random.Random(42).shuffle(tiles)
    return tiles


def bench_layer(args: argparse.Namespace, url: str, store: Path) -> tuple[Path, Path, int]:
    """The test image ingested as layer ``bench``: (image, its COG, native zoom)."""
    from ingest.raster.job import ingest_raster

    image = write_test_image(OUT / f"texture_{args.size}.tif", args.size, args.size)
    os.environ["DATABASE_URL"] = url
    report = ingest_raster([image], "bench", database_url=url, store=store)
    return image, Path(report.sources[0].uri), report.sources[0].zoom


def ugvmap_server(url: str, store: str, workers: int,
                  **env: str) -> tuple[subprocess.Popen, str]:
    """``ugvmap serve`` on a free port (tile cache off unless ``env`` says otherwise)."""
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    cmd = [sys.executable, "-m", "cli", "serve", "--port", str(port), "--workers", str(workers),
           "--queue-workers", "0"]
    env = {"DATABASE_URL": url, "UGVMAP_RASTER_STORE": store, "UGVMAP_LOG_LEVEL": "WARNING",
           "UGVMAP_TILE_CACHE_MB": "0", **env}
    return start(cmd, env, f"{base}/healthz"), base


def report_line(name: str, r: dict[str, float]) -> None:
    """One result line of a wrk run."""
    print(f"  {name:22s}: {r['tiles_per_s']:8.1f} tiles/s  p50 {r['p50_ms']:6.1f} ms  "
          f"p99 {r['p99_ms']:6.1f} ms  errors {r['errors']}", flush=True)


def bench_tiles(args: argparse.Namespace, url: str, store: Path, cog: Path, native: int) -> None:
    """Tiles per second, ugvmap vs TiTiler on the same COG, at native and native-3 zooms."""
    titiler_python = ensure_titiler()
    results: dict[tuple[str, int], dict] = {}
    for zoom in (native, native - 3):
        tiles = tile_paths(cog, zoom)
        for name in ("ugvmap", "titiler"):
            if name == "ugvmap":
                proc, base = ugvmap_server(url, str(store), args.workers)
                paths = [f"/tiles/bench/{zoom}/{x}/{y}.png" for x, y in tiles]
            else:
                port = free_port()
                base = f"http://127.0.0.1:{port}"
                proc = start([str(titiler_python), "-m", "uvicorn",
                              "titiler.application.main:app", "--host", "127.0.0.1", "--port",
                              str(port), "--workers", str(args.workers), "--no-access-log",
                              "--log-level", "warning"], {}, f"{base}/healthz")
                paths = [f"/cog/tiles/WebMercatorQuad/{zoom}/{x}/{y}.png?url=file://{cog}"
                         for x, y in tiles]
            try:
                results[(name, zoom)] = wrk(base, paths, args.duration, args.workers)
            finally:
                stop(proc)
            report_line(f"{name} z{zoom} ({len(tiles)} tiles)", results[(name, zoom)])
        ratio = results[("ugvmap", zoom)]["tiles_per_s"] / results[("titiler", zoom)][
            "tiles_per_s"]
        kind = "native" if zoom == native else "overview"
        print(f"RATIO tiles/s ugvmap/titiler at z{zoom} ({kind}), {args.workers} worker(s): "
              f"{ratio:.2f}x (target >= 1.5)", flush=True)


def bench_front_cache(args: argparse.Namespace, url: str, store: Path, cog: Path,
                      native: int) -> None:
    """Tiles/s through the nginx front cache (all HITs) vs the same nginx serving the same
    PNGs as static files."""
    from cli.ops.frontcache.nginx import FrontCache

    tiles = tile_paths(cog, native)
    app, _ = ugvmap_server(url, str(store), args.workers, UGVMAP_TILE_CACHE_MB="64")
    app_addr = app.args[app.args.index("--port") + 1]
    try:
        with tempfile.TemporaryDirectory() as work:
            static = Path(work) / "static"
            static_port = free_port()
            extra = (f"    server {{\n        listen 127.0.0.1:{static_port};\n"
                     f"        root {static};\n    }}\n")
            with FrontCache(Path(work) / "nginx", "127.0.0.1", free_port(),
                            f"127.0.0.1:{app_addr}", extra_servers=extra) as front:
                template = httpx.get(f"{front.url}/layers/bench/tilejson.json").json()["tiles"][0]
                cached: list[str] = []
                with httpx.Client(timeout=30) as http:
                    for x, y in tiles:  # fill the cache, keep each body as a static file
                        tile = template.format(z=native, x=x, y=y)
                        resp = http.get(tile)
                        resp.raise_for_status()
                        dst = static / str(native) / str(x) / f"{y}.png"
                        dst.parent.mkdir(parents=True, exist_ok=True)
                        dst.write_bytes(resp.content)
                        cached.append(tile.removeprefix(front.url))
                    hits = sum(http.get(front.url + p).headers["x-cache-status"] == "HIT"
                               for p in cached)
                print(f"  {len(tiles)} distinct tiles at z{native}, {hits} HITs on a second "
                      "pass", flush=True)
                through = wrk(front.url, cached, args.duration)
                report_line("nginx cache (HIT)", through)
                direct = wrk(f"http://127.0.0.1:{static_port}",
                             [f"/{native}/{x}/{y}.png" for x, y in tiles], args.duration)
                report_line("nginx static files", direct)
    finally:
        stop(app)
    print(f"RATIO tiles/s nginx front cache / nginx static files: "
          f"{through['tiles_per_s'] / direct['tiles_per_s']:.2f}x (target >= 0.5)", flush=True)


def bench_s3(args: argparse.Namespace, url: str, store: Path, image: Path, cog: Path,
             native: int) -> None:
    """Tiles/s with the COG on a local S3 server (GDAL /vsis3/) vs on local disk."""
    from moto.server import ThreadedMotoServer

    from app.tiles.store import s3_client
    from ingest.raster.job import ingest_raster

    logging.getLogger("werkzeug").setLevel(logging.WARNING)  # moto's per-request lines
    port = free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    os.environ.update({"AWS_ACCESS_KEY_ID": "bench", "AWS_SECRET_ACCESS_KEY": "bench",
                       "AWS_REGION": "us-east-1", "AWS_VIRTUAL_HOSTING": "FALSE",
                       "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}"})
    try:
        s3_client().create_bucket(Bucket="ugvmap-bench")
        s3_uri = "s3://ugvmap-bench/rasters"
        ingest_raster([image], "bench-s3", database_url=url, store=s3_uri)
        tiles = tile_paths(cog, native)
        small_caches = {"GDAL_CACHEMAX": "8", "CPL_VSIL_CURL_CACHE_SIZE": str(4 << 20)}
        results = {}
        for name, layer, where in (("local disk", "bench", str(store)),
                                   ("S3 (moto, /vsis3/)", "bench-s3", s3_uri)):
            proc, base = ugvmap_server(url, where, args.workers, **small_caches)
            try:
                results[name] = wrk(base, [f"/tiles/{layer}/{native}/{x}/{y}.png"
                                           for x, y in tiles], args.duration, args.workers)
            finally:
                stop(proc)
            report_line(name, results[name])
    finally:
        server.stop()
    ratio = results["S3 (moto, /vsis3/)"]["tiles_per_s"] / results["local disk"]["tiles_per_s"]
    print(f"RATIO tiles/s S3 / local disk at z{native}, {args.workers} worker(s): "
          f"{ratio:.2f}x", flush=True)


def timed_child(code: str, env: dict[str, str]) -> tuple[float, float]:
    """Run python ``code`` in a child; return (wall s, peak RSS MiB) of that child alone."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, env={**os.environ, **env})
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if status != 0:
        raise RuntimeError(f"child failed ({status}): {code}")
    return wall, usage.ru_maxrss / 1024


def bench_ingest(args: argparse.Namespace, url: str, store: Path) -> None:
    """Time and peak RSS of our ingest against a bare GDAL COG-driver call on the same mosaic."""
    width, height = args.mosaic
    image = write_test_image(OUT / f"mosaic_{width}x{height}.tif", width, height)
    gdal_out = OUT / "gdal_cog.tif"
    ugv = ("from pathlib import Path; from ingest.raster.job import ingest_raster; "
           f"ingest_raster([Path({str(image)!r})], 'mosaic', kind='ipm-mosaic', "
           f"database_url={url!r}, store=Path({str(store)!r}))")
    gdal = ("import rasterio, rasterio.shutil; from ingest.raster.cog import "
            "bound_block_cache, cog_options; bound_block_cache(); "  # the same block cache
            f"rasterio.shutil.copy({str(image)!r}, {str(gdal_out)!r}, driver='COG', "
            "**cog_options('uint8', 3))")
    env = {"DATABASE_URL": url}
    ugv_s, ugv_mb = timed_child(ugv, env)
    gdal_s, gdal_mb = timed_child(gdal, env)
    print(f"  ugvmap ingest {width}x{height}: {ugv_s:6.1f} s, peak RSS {ugv_mb:6.0f} MiB")
    print(f"  GDAL COG driver          : {gdal_s:6.1f} s, peak RSS {gdal_mb:6.0f} MiB")
    print(f"RATIO ingest time ugvmap/GDAL: {ugv_s / gdal_s:.2f}x (target <= 1.3); "
          f"peak RSS {ugv_mb:.0f} MiB (target < 2048)")
    gdal_out.unlink(missing_ok=True)


def main() -> None:
    """Run the selected benchmarks on a scratch database."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--duration", type=int, default=15, help="seconds per wrk run")
    parser.add_argument("--size", type=int, default=6000, help="tile test image side, px")
    parser.add_argument("--mosaic", type=int, nargs=2, default=(28000, 7000))
    parser.add_argument("--skip-tiles", action="store_true", help="no ugvmap vs TiTiler run")
    parser.add_argument("--skip-cache", action="store_true", help="no front-cache run")
    parser.add_argument("--skip-s3", action="store_true", help="no object-storage run")
    parser.add_argument("--skip-ingest", action="store_true")
    args = parser.parse_args()
    if shutil.which("wrk") is None:
        sys.exit("wrk not found: apt-get install wrk (scripts/setup.sh installs it)")
    sys.path.insert(0, str(REPO))
    url = database()
    store = OUT / f"store-{uuid.uuid4().hex[:6]}"
    print(json.dumps({"cpus": os.cpu_count(), "workers": args.workers,
                      "rasterio": rasterio.__version__, "gdal": rasterio.__gdal_version__}))
    try:
        if not (args.skip_tiles and args.skip_cache and args.skip_s3):
            image, cog, native = bench_layer(args, url, store)
        if not args.skip_tiles:
            print("tile throughput (PNG 256 px, uncached, same COG):", flush=True)
            bench_tiles(args, url, store, cog, native)
        if not args.skip_cache:
            print("front cache (versioned tiles through nginx vs nginx static files):",
                  flush=True)
            bench_front_cache(args, url, store, cog, native)
        if not args.skip_s3:
            print("object storage (tiles from S3 via /vsis3/ vs local disk, tile cache off):",
                  flush=True)
            bench_s3(args, url, store, image, cog, native)
        if not args.skip_ingest:
            print("ingest of an RGB mosaic (JPEG COG, web-mercator grid):", flush=True)
            bench_ingest(args, url, store)
    finally:
        drop_database(url)
        shutil.rmtree(store, ignore_errors=True)


if __name__ == "__main__":
    main()
