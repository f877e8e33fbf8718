"""Road network import: read GeoJSON / GeoPackage / OSM, node into a topology, store in PostGIS.

``import_network`` is the file entry point; ``write_network`` stores any attributed lines
(road extraction writes through it too), so every source obeys the same topology rules.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from sqlalchemy.orm import Session

from ingest.network.coordinates import check_lonlat_lines
from ingest.network.file_reader import NetworkFileError, read_geojson, read_ogr
from ingest.network.model import FeatureLike, ImportSummary, NodePoint, RoadAttributes, RoadLine
from ingest.network.writer import NetworkExistsError, write_network

__all__ = ["FeatureLike", "ImportSummary", "NetworkExistsError", "NetworkFileError",
           "NodePoint", "RoadAttributes", "RoadLine", "import_network", "write_network"]

OSM_SUFFIXES = (".osm", ".osm.pbf", ".pbf", ".osm.bz2", ".osm.gz")
GEOJSON_SUFFIXES = (".geojson", ".json")


def import_network(session: Session, path: Path, network: str, *, replace: bool = False,
                   progress: Callable[[str], None] | None = None) -> ImportSummary:
    """Import a road file into network ``network`` (created if missing) in the caller's
    transaction. OSM files connect at shared nodes; other files are noded where lines cross
    or touch, unless they carry ``source_node``/``target_node`` (a topology already).
    ``progress`` is called with the name of each finished stage (read, node, store)."""
    path = Path(path)
    if not path.is_file():
        raise NetworkFileError(f"{path}: no such file")
    name = path.name.lower()
    if name.endswith(OSM_SUFFIXES):
        from ingest.network.osm_reader import read_osm

        try:
            lines, points = read_osm(path)
        except RuntimeError as exc:  # libosmium reports parse errors as RuntimeError
            raise NetworkFileError(f"{path.name}: not a readable OSM file ({exc})") from exc
        topological = True
    elif name.endswith(GEOJSON_SUFFIXES):
        lines, points, topological = read_geojson(path)
    else:
        lines, points, topological = read_ogr(path)
    if not lines:
        raise NetworkFileError(f"{path.name}: no road lines found")
    check_lonlat_lines(lines, path.name)
    if progress:
        progress("read")
    return write_network(session, network, lines, replace=replace,
                         node_crossings=not topological, node_points=points,
                         progress=progress)
