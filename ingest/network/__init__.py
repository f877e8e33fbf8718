"""Road network import: read GeoJSON / GeoPackage / OSM, node into a topology, store in PostGIS.

``import_network`` is the file entry point; ``write_network`` stores any attributed lines
(road extraction writes through it too), so every source obeys the same topology rules.
"""

from __future__ import annotations

from pathlib import Path

from sqlalchemy.orm import Session

from ingest.network.coordinates import check_lonlat_lines
from ingest.network.file_reader import NetworkFileError, read_geojson, read_ogr
from ingest.network.model import FeatureLike, ImportSummary, NodePoint, RoadAttributes, RoadLine
from ingest.network.writer import (
    NetworkExistsError,
    NoLinesError,
    Progress,
    store_lines,
    write_network,
)

__all__ = ["FeatureLike", "ImportSummary", "NetworkExistsError", "NetworkFileError",
           "NodePoint", "RoadAttributes", "RoadLine", "import_network", "write_network"]

OSM_SUFFIXES = (".osm", ".osm.pbf", ".pbf", ".osm.bz2", ".osm.gz")
GEOJSON_SUFFIXES = (".geojson", ".json")


def import_network(session: Session, path: Path, network: str, *, replace: bool = False,
                   progress: Progress | None = None) -> ImportSummary:
    """Import a road file into network ``network`` (created if missing) in the caller's
    transaction. OSM files connect at shared nodes and are streamed (read twice, never held in
    memory); other files are read whole and noded where lines cross or touch, unless they
    carry ``source_node``/``target_node`` (a topology already).
    ``progress(message, fraction)`` is told how far the import is."""
    path = Path(path)
    if not path.is_file():
        raise NetworkFileError(f"{path}: no such file")
    name = path.name.lower()
    try:
        if name.endswith(OSM_SUFFIXES):
            from ingest.network.osm_reader import read_osm

            return store_lines(session, network, lambda: read_osm(path), replace=replace,
                               allow_empty=False, progress=progress)
        if name.endswith(GEOJSON_SUFFIXES):
            lines, points, topological = read_geojson(path)
        else:
            lines, points, topological = read_ogr(path)
        if not lines:
            raise NoLinesError("no road lines found")
        check_lonlat_lines(lines, path.name)
    except NoLinesError as exc:
        raise NetworkFileError(f"{path.name}: {exc}") from exc
    return write_network(session, network, lines, replace=replace,
                         node_crossings=not topological, node_points=points,
                         progress=progress)
