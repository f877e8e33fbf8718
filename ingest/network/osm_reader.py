"""Read road lines and traffic lights from ``.osm`` / ``.osm.pbf`` with pyosmium.

Ways are kept whole here (except across nodes missing from the extract); splitting them at
shared OSM nodes is the noding step's job (shared nodes are shared coordinates), so OSM and
every other format follow one topology rule. Ways that cross without a shared node
(bridges, tunnels) are correctly left unconnected: OSM's topology is explicit, so OSM imports
do not node crossings.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import osmium

from ingest.network.file_reader import NetworkFileError
from ingest.network.model import NodePoint, RoadLine
from ingest.network.osm_tags import EXTERNAL_ID_TAG, attributes_from_tags, is_road

TRAFFIC_SIGNALS = "traffic_signals"


def read_osm(path: Path) -> Iterator[RoadLine | NodePoint]:
    """Every road way as RoadLines (coordinates resolved), and node attributes: traffic
    lights, and nodes our own OSM export tagged with their ``external_id``. A generator: each
    call reads the file again, so a country-sized extract is never held in memory."""
    # The location index sees every node; Python only sees objects with the keys we use.
    processor = osmium.FileProcessor(str(path), osmium.osm.NODE | osmium.osm.WAY) \
        .with_locations().with_filter(osmium.filter.KeyFilter("highway", EXTERNAL_ID_TAG))
    try:
        for obj in processor:
            if isinstance(obj, osmium.osm.Node):
                light = obj.tags.get("highway") == TRAFFIC_SIGNALS
                named = obj.tags.get(EXTERNAL_ID_TAG)
                if (light or named) and obj.location.valid():
                    yield NodePoint((obj.location.lon, obj.location.lat), traffic_light=light,
                                    external_id=named or f"n{obj.id}")
                continue
            assert isinstance(obj, osmium.osm.Way)  # the processor yields only nodes and ways
            tags = dict(obj.tags)
            if not is_road(tags):
                continue
            attributes = attributes_from_tags(tags, external_id=f"w{obj.id}")
            for run in _located_runs(obj.nodes):
                if len(run) > 1:
                    yield RoadLine(run, attributes)
    except RuntimeError as exc:  # libosmium reports parse errors as RuntimeError
        raise NetworkFileError(f"{path.name}: not a readable OSM file ({exc})") from exc


def _located_runs(nodes: osmium.osm.WayNodeList) -> list[list[tuple[float, float]]]:
    """Split a way where node locations are missing (ways cut by the extract boundary), so
    no straight line is drawn across the gap."""
    runs: list[list[tuple[float, float]]] = [[]]
    for n in nodes:
        if n.location.valid():
            runs[-1].append((n.lon, n.lat))
        elif runs[-1]:
            runs.append([])
    return runs
