"""The embedded PostGIS cluster that ``make demo`` / ``make test`` run when no DATABASE_URL is set.

Why a private cluster rather than the machine's default one: a fresh user machine has no
PostgreSQL server at all, and on a developer machine we must not touch someone else's
databases. The cluster lives under ``.data/postgres``, listens on 127.0.0.1 on its own port
and trusts local connections. PostgreSQL refuses to run as root, so as root (CI, containers)
the cluster files are owned by and the server runs as the ``postgres`` system user.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import subprocess
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import psycopg
from psycopg.conninfo import make_conninfo

from app.errors import UserError
from app.settings import Settings

EXTENSIONS = ("postgis", "pgrouting")
DEBIAN_PACKAGES = ("postgresql-15-postgis-3", "postgresql-15-pgrouting")


class EmbeddedDbError(UserError):
    """A problem the user can fix (port taken, packages missing); the message says how."""


@dataclass(frozen=True)
class Cluster:
    """Where one private PostgreSQL cluster lives and listens; nothing else is needed to manage it.
    """
    data_dir: Path
    port: int
    database: str

    @property
    def log_file(self) -> Path:
        """PostgreSQL's own log, next to (not inside) the data directory so initdb finds it empty.
        """
        return self.data_dir.parent / "postgres.log"

    @property
    def initialized(self) -> bool:
        """Whether initdb has run: PG_VERSION is the first file it writes and the last it needs."""
        return (self.data_dir / "PG_VERSION").exists()


def cluster_from(settings: Settings) -> Cluster:
    """The cluster the settings describe (data dir, port, database name)."""
    return Cluster(settings.pg_data_dir, settings.pg_port, settings.pg_database)


@lru_cache(maxsize=1)
def pg_bindir() -> Path:
    """Locate the server binaries (initdb, pg_ctl); Debian keeps them off PATH."""
    candidates = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), reverse=True)
    preferred = [c for c in candidates if "/15/" in c] or candidates
    if preferred:
        return Path(preferred[0]).parent
    found = shutil.which("initdb")
    if found:
        return Path(found).parent
    raise EmbeddedDbError(
        "PostgreSQL server binaries not found. Install them with "
        "`apt-get install postgresql-15 " + " ".join(DEBIAN_PACKAGES) + "`, or set "
        "DATABASE_URL to an existing PostGIS database."
    )


def check_extensions_installed(bindir: Path) -> None:
    """Fail early, with the fix, when PostGIS or pgRouting packages are missing."""
    sharedir = subprocess.run(
        [str(bindir / "pg_config"), "--sharedir"], capture_output=True, text=True, check=False
    ).stdout.strip() or "/usr/share/postgresql/15"
    missing = [e for e in EXTENSIONS if not Path(sharedir, "extension", f"{e}.control").exists()]
    if missing:
        raise EmbeddedDbError(
            f"PostgreSQL extension(s) {', '.join(missing)} are not installed. Run "
            f"`sudo apt-get install {' '.join(DEBIAN_PACKAGES)}` (or `make setup` as root), "
            "or set DATABASE_URL to a database that has them."
        )


def _as_server_user(cmd: list[str]) -> list[str]:
    if os.geteuid() != 0:
        return cmd
    try:
        pwd.getpwnam("postgres")
    except KeyError as exc:
        raise EmbeddedDbError(
            "Running as root but there is no `postgres` system user to run the server as; "
            "install Debian's postgresql package or run as an ordinary user."
        ) from exc
    return ["runuser", "-u", "postgres", "--", *cmd]


def _run(cmd: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(_as_server_user(cmd), capture_output=True, text=True, check=False)


def _check_traversable(path: Path) -> None:
    """As root, the postgres user must be able to reach the data directory."""
    if os.geteuid() != 0:
        return
    for parent in [path, *path.parents]:
        if parent.exists() and not os.stat(parent).st_mode & 0o001:
            raise EmbeddedDbError(
                f"{parent} is not traversable by the postgres user, which runs the embedded "
                f"server as root; `chmod o+x {parent}` or set UGVMAP_DATA_DIR elsewhere."
            )


def init(cluster: Cluster) -> None:
    """Create the cluster once (initdb, as the postgres user when run as root), checking first that
    PostGIS and pgRouting are installed, since a cluster without them fails later and less
    clearly."""
    bindir = pg_bindir()
    check_extensions_installed(bindir)
    if cluster.initialized:
        return
    cluster.data_dir.mkdir(parents=True, exist_ok=True)
    _check_traversable(cluster.data_dir)
    if os.geteuid() == 0:
        shutil.chown(cluster.data_dir, "postgres", "postgres")
        shutil.chown(cluster.data_dir.parent, "postgres", "postgres")
    os.chmod(cluster.data_dir, 0o700)
    proc = _run(
        [str(bindir / "initdb"), "-D", str(cluster.data_dir), "-U", "postgres",
         "--auth=trust", "-E", "UTF8", "--locale=C.UTF-8"]
    )
    if proc.returncode != 0:
        raise EmbeddedDbError(f"initdb failed:\n{proc.stdout}\n{proc.stderr}")
    conf = cluster.data_dir / "postgresql.auto.conf"
    with conf.open("a") as fh:
        fh.write(
            f"port = {cluster.port}\n"
            "listen_addresses = '127.0.0.1'\n"
            "unix_socket_directories = ''\n"
            "max_connections = 200\n"
            "shared_buffers = 256MB\n"
            "fsync = on\n"
        )


def is_running(cluster: Cluster) -> bool:
    """Whether *this* cluster's postmaster runs (not merely something on its port)."""
    if not cluster.initialized:
        return False
    proc = _run([str(pg_bindir() / "pg_ctl"), "-D", str(cluster.data_dir), "status"])
    return proc.returncode == 0


def accepts_connections(cluster: Cluster) -> bool:
    """Whether the server answers a real connection (a PID file alone can be stale)."""
    try:
        with psycopg.connect(_dsn(cluster, "postgres"), connect_timeout=2):
            return True
    except psycopg.OperationalError:
        return False


def _dsn(cluster: Cluster, database: str) -> str:
    return f"host=127.0.0.1 port={cluster.port} user=postgres dbname={database}"


def start(cluster: Cluster, timeout_s: float = 30.0) -> None:
    """Initialise on first use, start if stopped, and make sure the database has PostGIS."""
    init(cluster)
    if not is_running(cluster):
        if accepts_connections(cluster):
            raise EmbeddedDbError(
                f"port {cluster.port} is taken by another PostgreSQL server, not the one in "
                f"{cluster.data_dir}; stop it or choose another port with UGVMAP_PG_PORT."
            )
        if os.geteuid() == 0 and cluster.log_file.parent.exists():
            shutil.chown(cluster.log_file.parent, "postgres", "postgres")
        proc = _run(
            [str(pg_bindir() / "pg_ctl"), "-D", str(cluster.data_dir), "-l",
             str(cluster.log_file), "-w", "-t", str(int(timeout_s)), "start"]
        )
        if proc.returncode != 0:
            log = cluster.log_file.read_text()[-2000:] if cluster.log_file.exists() else ""
            raise EmbeddedDbError(
                f"PostgreSQL did not start on port {cluster.port}: {proc.stderr.strip()}\n{log}"
            )
    deadline = time.monotonic() + timeout_s
    while not accepts_connections(cluster):
        if time.monotonic() > deadline:
            raise EmbeddedDbError(f"PostgreSQL on port {cluster.port} does not accept connections")
        time.sleep(0.2)
    ensure_database(_dsn(cluster, "postgres"), cluster.database)


def ensure_database(admin_dsn: str, database: str) -> None:
    """Create ``database`` with the PostGIS and pgRouting extensions if it does not exist."""
    with psycopg.connect(admin_dsn, autocommit=True) as conn:
        exists = conn.execute(
            "SELECT 1 FROM pg_database WHERE datname = %s", (database,)
        ).fetchone()
        if not exists:
            conn.execute(f'CREATE DATABASE "{database}"')
    db_dsn = make_conninfo(admin_dsn, dbname=database)
    with psycopg.connect(db_dsn, autocommit=True) as conn:
        for ext in EXTENSIONS:
            conn.execute(f"CREATE EXTENSION IF NOT EXISTS {ext} CASCADE")


def stop(cluster: Cluster) -> None:
    """Stop the server with a fast shutdown (open sessions are cut, data is kept); a no-op when it
    is not running."""
    if not cluster.initialized or not is_running(cluster):
        return
    pg_ctl = str(pg_bindir() / "pg_ctl")
    proc = _run([pg_ctl, "-D", str(cluster.data_dir), "-m", "fast", "-w", "stop"])
    if proc.returncode != 0:
        raise EmbeddedDbError(f"pg_ctl stop failed: {proc.stderr.strip()}")


def status(cluster: Cluster) -> str:
    """One line for ``ugvmap db status``: initialised or not, running or stopped, and where."""
    if not cluster.initialized:
        other = accepts_connections(cluster)
        return f"not initialised ({cluster.data_dir})" + (
            f"; but a PostgreSQL server answers on 127.0.0.1:{cluster.port}: a cluster of "
            "another data directory? (UGVMAP_DATA_DIR, UGVMAP_PG_PORT)" if other else "")
    state = "running" if is_running(cluster) else "stopped"
    return f"{state} on 127.0.0.1:{cluster.port} ({cluster.data_dir})"
