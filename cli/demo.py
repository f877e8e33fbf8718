"""``ugvmap demo`` and ``ugvmap serve``: what ``make demo`` runs."""

from __future__ import annotations

import errno
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType

import click

from app.errors import UserError
from app.settings import get_settings


@click.command("demo")
@click.option("--shared-data", type=click.Path(path_type=Path, file_okay=False),
              default=Path("../shared/data"), show_default=True,
              help="Sample data folder; a synthetic town is generated when it is absent.")
def demo(shared_data: Path) -> None:
    """Load the demo layers and networks (idempotent) and print an editor token."""
    from ingest.demo import load_demo

    token = load_demo(shared_data, get_settings().data_dir / "demo-editor-token", click.echo)
    click.echo(f"editor token for the web map: {token}")


def refuse_busy_port(host: str, port: int) -> None:
    """Say in one line that the port is taken and how to choose another, before uvicorn
    would (as a JSON log line, after loading the whole app). A port freed a moment later
    than this check still gets uvicorn's own error."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn binds
        try:
            probe.bind((host, port))
        except OSError as exc:
            if exc.errno != errno.EADDRINUSE:
                raise UserError(f"cannot listen on {host}:{port} ({exc.strerror})") from exc
            raise UserError(
                f"port {port} on {host} is in use (another `ugvmap serve`, or another "
                f"program): choose another with --port N, UGVMAP_PORT=N, or "
                f"`make demo PORT=N`") from exc


@click.command("serve")
@click.option("--host", default="127.0.0.1", show_default=True)
@click.option("--port", default=8000, show_default=True, type=int, envvar="UGVMAP_PORT",
              help="TCP port to listen on (env UGVMAP_PORT).")
@click.option("--workers", default=1, show_default=True, type=int)
@click.option("--queue-workers", default=1, show_default=True, type=click.IntRange(0, 64),
              help="`ugvmap worker` processes started beside the server (road previews and "
                   "queued jobs run on them); 0 when workers run elsewhere.")
@click.option("--front-cache", is_flag=True,
              help="Put nginx (a disk cache of versioned tiles) on --port, the app behind it.")
@click.option("--app-port", type=int, help="With --front-cache: the app's own port "
              "(default: --port + 1, on 127.0.0.1).")
@click.option("--cache-size", default="1g", show_default=True,
              help="With --front-cache: nginx's max_size for the tile cache.")
def serve(host: str, port: int, workers: int, queue_workers: int, front_cache: bool,
          app_port: int | None, cache_size: str) -> None:
    """Serve the web map, tiles, features and routes over HTTP, with queue workers beside."""
    import uvicorn

    from app.api.wire import ServiceHttpProtocol
    from app.logs import logging_config

    settings = get_settings()

    def run(app_host: str, app_port: int) -> None:
        # httptools, header names respelled as QGIS 3.34 needs them (app.api.wire).
        uvicorn.run("app.main:create_app", factory=True, host=app_host, port=app_port,
                    workers=workers, log_config=logging_config(settings.log_level),
                    access_log=False, http=ServiceHttpProtocol)

    refuse_busy_port(host, port)
    with queue_worker_processes(queue_workers):
        if not front_cache:
            run(host, port)
            return
        from cli.ops.frontcache.nginx import FrontCache

        behind = app_port or port + 1
        workdir = settings.data_dir / "front-cache"
        with FrontCache(workdir, host, port, f"127.0.0.1:{behind}", max_size=cache_size,
                        workers=workers):
            click.echo(f"front cache (nginx) on http://{host}:{port} -> app on "
                       f"127.0.0.1:{behind}; cache and config in {workdir}", err=True)
            run("127.0.0.1", behind)


@contextmanager
def queue_worker_processes(count: int) -> Iterator[None]:
    """``count`` ``ugvmap worker`` processes while the block runs, stopped (SIGTERM: running
    tasks finish) when it ends. Why beside the server: the web map's previews are queued jobs
    (the server never runs ingest code), so a server alone would leave them queued forever.
    Separate processes, not threads: an extraction holds its cores for seconds, and the
    server's event loop must not wait on it."""
    procs = [subprocess.Popen([sys.executable, "-m", "cli", "worker", "--concurrency", "1"])
             for _ in range(count)]
    # uvicorn ends on SIGTERM by raising it again once it has shut down; with the default
    # handler that kills this process before the ``finally`` below, leaving the workers
    # running. A handler of our own turns it into SystemExit, so they are stopped.
    previous = signal.signal(signal.SIGTERM, _exit_on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        for proc in procs:
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()


def _exit_on_sigterm(signum: int, frame: FrameType | None) -> None:
    raise SystemExit(128 + signum)
