"""A real ``ugvmap serve`` process for tests and benchmarks that need HTTP over a socket
(several workers, the access log, the front cache), and the free port it listens on."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from urllib.parse import urlsplit

import httpx

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    """A TCP port free on the loopback interface right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def running_server(env: dict[str, str], workers: int = 1,
                   timeout_s: float = 30.0, drop: tuple[str, ...] = (),
                   queue_workers: int = 0) -> Iterator[str]:
    """Run ``ugvmap serve`` as a real subprocess and yield its base URL (``drop``: variables
    of this process's environment it does not get). ``queue_workers``: the ``ugvmap worker``
    processes it starts beside (none by default: tests that run queued tasks by hand must not
    race a worker).

    Its output (one JSON log line per request) goes to a temporary file, not a pipe: nobody
    reads a pipe while the tests run, and once its buffer is full the server blocks on logging.
    """
    port = free_port()
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "cli", "serve", "--port", str(port),
             "--workers", str(workers), "--queue-workers", str(queue_workers)],
            cwd=REPO, env={k: v for k, v in {**os.environ, **env}.items() if k not in drop},
            stdout=log, stderr=subprocess.STDOUT,
        )
        base = f"http://127.0.0.1:{port}"
        try:
            deadline = time.monotonic() + timeout_s
            while True:
                try:
                    httpx.get(f"{base}/healthz", timeout=1.0)
                    break
                except httpx.TransportError:
                    if proc.poll() is not None or time.monotonic() > deadline:
                        log.seek(0)
                        out = log.read().decode(errors="replace")
                        raise RuntimeError(f"server did not start:\n{out}") from None
                    time.sleep(0.1)
            yield base
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()


def raw_exchange(base: str, payload: bytes) -> bytes:
    """Send ``payload`` as it is to the server at ``base`` and read until it closes the
    connection: for what an HTTP client would not send or would not show (malformed requests,
    pipelining, header names as spelled on the wire)."""
    parts = urlsplit(base)
    with socket.create_connection((parts.hostname, parts.port), timeout=10) as raw:
        raw.sendall(payload)
        answer = b""
        while chunk := raw.recv(65536):
            answer += chunk
    return answer
