"""MBTiles 1.3 archives, written with the standard library's sqlite3.

MBTiles rather than PMTiles because the standard GIS tools open it: GDAL (and so rasterio and
QGIS) reads and writes MBTiles rasters, while GDAL reads PMTiles rasters only from 3.14 on.
The tiles are the served bytes as they are (GDAL would re-encode them): ``tiles`` holds them
under TMS rows (``2^z - 1 - y``), ``metadata`` names the archive, its format, bounds, centre
and zooms, as the specification asks.
"""

from __future__ import annotations

import sqlite3
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType

SCHEMA = """
CREATE TABLE metadata (name TEXT, value TEXT);
CREATE TABLE tiles (zoom_level INTEGER, tile_column INTEGER, tile_row INTEGER, tile_data BLOB);
CREATE UNIQUE INDEX tile_index ON tiles (zoom_level, tile_column, tile_row);
CREATE UNIQUE INDEX name ON metadata (name);
"""


class MBTilesWriter:
    """One archive being written (complete after :meth:`close`)."""

    def __init__(self, path: Path, metadata: Mapping[str, str]) -> None:
        path.unlink(missing_ok=True)
        self.path = path
        self.count = 0
        self._db = sqlite3.connect(path)
        self._db.executescript(SCHEMA)
        self._db.executemany("INSERT INTO metadata VALUES (?, ?)", sorted(metadata.items()))

    def add(self, z: int, x: int, y: int, data: bytes) -> None:
        """Tile z/x/y (XYZ addressing, as served)."""
        self._db.execute("INSERT INTO tiles VALUES (?, ?, ?, ?)", (z, x, 2**z - 1 - y, data))
        self.count += 1

    def close(self) -> None:
        """Commit and close (``VACUUM`` keeps the file compact and deterministic in size)."""
        self._db.commit()
        self._db.execute("VACUUM")
        self._db.close()

    def __enter__(self) -> MBTilesWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self._db.close()
            self.path.unlink(missing_ok=True)
