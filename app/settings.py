"""Runtime settings, read from the environment (prefix ``UGVMAP_``) with ``DATABASE_URL`` as-is.

Everything defaults to a self-contained local setup: an embedded PostGIS cluster under
``<data dir>/postgres`` and a raster store under ``<data dir>/rasters``, so ``make demo``
works on a fresh machine; ``DATABASE_URL`` points the whole service at any other PostGIS
instead.

The data directory does not depend on the working directory: it is the ``.data`` folder of
the source checkout ugvmap runs from (where ``make demo`` puts it), or, for an installed
package, ``$XDG_DATA_HOME/ugvmap``. It used to be ``.data`` under the current directory, so
``ugvmap ingest raster`` run from another folder wrote its COGs into a second store that the
server (started elsewhere) never read, while both reached the same database by its port.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

CHECKOUT = Path(__file__).resolve().parents[1]


def default_data_dir() -> Path:
    """``<checkout>/.data`` when running from a source checkout (``pyproject.toml`` next to
    ``app/``: the development and ``make demo`` case), else ``$XDG_DATA_HOME/ugvmap``
    (``~/.local/share/ugvmap``)."""
    if (CHECKOUT / "pyproject.toml").is_file():
        return CHECKOUT / ".data"
    xdg = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(xdg) / "ugvmap"


class Settings(BaseSettings):
    """Service settings from ``UGVMAP_*`` variables and ``DATABASE_URL``."""
    model_config = SettingsConfigDict(env_prefix="UGVMAP_", extra="ignore")

    database_url_override: str | None = Field(default=None, validation_alias="DATABASE_URL")
    data_dir: Path = Field(default_factory=default_data_dir)
    pg_port: int = 54329
    pg_database: str = "ugvmap"
    raster_store: str | None = None
    tile_cache_mb: int = 64
    log_level: str = "INFO"
    db_connect_timeout_s: int = 3
    # Least token role needed to read networks (features, tiles, history); unset: public.
    network_read_role: Literal["viewer", "editor", "admin"] | None = None
    # Least token role needed to read /jobs; unset: the network read role (public if unset too).
    # Whoever is not admin sees file names instead of absolute server paths.
    jobs_read_role: Literal["viewer", "editor", "admin"] | None = None
    # A running job renews its lease every third of this; a job whose lease ran out belongs
    # to a dead process. Queue workers use it for their procrastinate heartbeat too.
    job_lease_s: float = Field(default=30.0, gt=0)
    # A queued task whose worker died is retried on another worker up to this many runs.
    job_max_attempts: int = Field(default=3, ge=1)
    # Largest request body, counted while it is read (chunked bodies too): 413 beyond it.
    max_body_bytes: int = Field(default=1_000_000, ge=0)
    # Web pages (origins) allowed to call the API from a browser, comma-separated: reads
    # (GET/HEAD without a token) from any page by default; writes and requests carrying a
    # token only from the pages listed (none by default).
    cors_read_origins: str = "*"
    cors_write_origins: str = ""
    # Writes without If-Match: "optional" (default) applies them to the current version and
    # records the overwritten one in the history (QGIS never sends If-Match, and editing from
    # QGIS is the point of OGC API Features Part 4); "required" refuses them with 428. A stale
    # If-Match is a 412 either way, so clients that send one never lose an update.
    if_match: Literal["optional", "required"] = "optional"

    @field_validator("data_dir")
    @classmethod
    def _absolute(cls, value: Path) -> Path:
        """An explicit relative ``UGVMAP_DATA_DIR`` is taken from where it was given, once."""
        return value.resolve()

    @property
    def embedded(self) -> bool:
        """True when no ``DATABASE_URL`` is given and the local cluster is ours to run."""
        return not self.database_url_override

    @property
    def database_url(self) -> str:
        """``DATABASE_URL`` normalised to the psycopg 3 driver, or the embedded cluster's URL."""
        if self.database_url_override:
            return normalize_url(self.database_url_override)
        return f"postgresql+psycopg://postgres@127.0.0.1:{self.pg_port}/{self.pg_database}"

    @property
    def cors_read_origin_list(self) -> list[str]:
        """Origins that may read, ``["*"]`` for any."""
        return _origins(self.cors_read_origins)

    @property
    def cors_write_origin_list(self) -> list[str]:
        """Origins that may write or send a token (never ``*``: credentials need names)."""
        return [o for o in _origins(self.cors_write_origins) if o != "*"]

    @property
    def pg_data_dir(self) -> Path:
        """The embedded cluster's data directory (absolute: pg_ctl runs elsewhere)."""
        return self.data_dir / "postgres"

    @property
    def raster_store_uri(self) -> str:
        """Where COGs are written: a directory by default, any GDAL-writable prefix if set."""
        return self.raster_store or str(self.data_dir / "rasters")

    @property
    def jobs_role(self) -> str | None:
        """The least role that reads ``/jobs`` (None: public)."""
        return self.jobs_read_role or self.network_read_role


def _origins(value: str) -> list[str]:
    """``"https://a.example, https://b.example"`` -> a list without trailing slashes (a
    browser's Origin header never has one)."""
    return [o.strip().rstrip("/") for o in value.replace(" ", ",").split(",") if o.strip()]


def normalize_url(url: str) -> str:
    """Accept libpq-style ``postgresql://`` URLs and use the psycopg 3 driver for them."""
    for prefix in ("postgresql://", "postgres://", "postgresql+psycopg2://"):
        if url.startswith(prefix):
            return "postgresql+psycopg://" + url[len(prefix) :]
    return url


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    """The settings, read once per process (tests clear the cache when they change the environment).
    """
    return Settings()
