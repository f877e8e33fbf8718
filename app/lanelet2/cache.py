"""Whole-network Lanelet2 maps kept as files, one per network version and origin.

Why: the whole-network map is the same file for everyone until the network changes, and
building it is the heaviest thing the service does (seconds of CPU and hundreds of MB for
Andorra; 50 clients asking at once took a median 54 s each and starved every other request,
issue 33). The first request of a version builds it once; every later one is sent the file.
Each map is kept gzipped beside it too (``.osm.gz``, compressed once when stored) and sent as
it is to a client that accepts gzip: compressing a 40 MB map per download, chunk by chunk on
the worker's event loop, was the loop's largest cost under load and held every light request
of that worker behind it (``bench/heavy_mix.py``). Files are written whole (built beside, then
renamed into place), so a reader never sees half a map, and any worker process may serve what
another built. A newer version's map replaces the older ones of its network, except the one
just before it (a download of it may still be starting).
"""

from __future__ import annotations

import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from isal import igzip

from app.settings import get_settings

NAME = re.compile(r"(?P<network>[0-9]+)-v(?P<version>[0-9]+)-(?P<origin>[^/]+)\.osm")


GZIP_LEVEL = 3  # ISA-L's best: paid once per version, not per download


@dataclass(frozen=True)
class CachedMap:
    """A stored map and the origin it was built around (lat, lon)."""

    path: Path
    origin: tuple[float, float]

    @property
    def gzipped(self) -> Path | None:
        """The map's gzip file, when it has one (stored maps do)."""
        gz = gzip_path(self.path)
        return gz if gz.is_file() else None


def gzip_path(path: Path) -> Path:
    """Where the gzipped copy of the map at ``path`` is kept."""
    return path.with_name(path.name + ".gz")


def cache_dir() -> Path:
    """``<data dir>/cache/lanelet2``."""
    return get_settings().data_dir / "cache" / "lanelet2"


def _key(origin: tuple[float, float] | None) -> str:
    return "auto" if origin is None else f"{origin[0]!r}_{origin[1]!r}"


def _path(network_id: int, version: int, origin: tuple[float, float] | None) -> Path:
    return cache_dir() / f"{network_id}-v{version}-{_key(origin)}.osm"


def cached(network_id: int, version: int, origin: tuple[float, float] | None
           ) -> CachedMap | None:
    """The stored map of this version around ``origin`` (None: the default one), if any."""
    path = _path(network_id, version, origin)
    try:
        lat, lon = path.with_suffix(".origin").read_text(encoding="utf-8").split(",")
    except FileNotFoundError:
        return None
    return CachedMap(path, (float(lat), float(lon))) if path.is_file() else None


def store(built: Path, network_id: int, version: int, origin: tuple[float, float] | None,
          map_origin: tuple[float, float]) -> CachedMap:
    """Move the map ``built`` (on the same file system) into the cache, and drop the maps of
    the network's versions before ``version - 1``."""
    path = _path(network_id, version, origin)
    path.parent.mkdir(parents=True, exist_ok=True)
    note = path.with_suffix(".origin")
    note_part = note.with_suffix(f".origin.{os.getpid()}")
    note_part.write_text(f"{map_origin[0]!r},{map_origin[1]!r}", encoding="utf-8")
    packed = gzip_path(built)
    with built.open("rb") as raw, igzip.open(packed, "wb", compresslevel=GZIP_LEVEL) as gz:
        shutil.copyfileobj(raw, gz, 1 << 20)
    # The origin, then the gzip, then the map: a map in place always has both.
    os.replace(note_part, note)
    os.replace(packed, gzip_path(path))
    os.replace(built, path)
    for old in path.parent.glob(f"{network_id}-v*.osm"):
        found = NAME.fullmatch(old.name)
        if found and int(found["version"]) < version - 1:
            old.unlink(missing_ok=True)
            gzip_path(old).unlink(missing_ok=True)
            old.with_suffix(".origin").unlink(missing_ok=True)
    return CachedMap(path, map_origin)
