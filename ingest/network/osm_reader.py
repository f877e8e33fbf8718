"""Read road lines and traffic lights from ``.osm`` / ``.osm.pbf`` with pyosmium.

Ways are kept whole here (except across nodes missing from the extract); splitting them at
shared OSM nodes is the noding step's job (shared nodes are shared coordinates), so OSM and
every other format follow one topology rule. Ways that cross without a shared node
(bridges, tunnels) are correctly left unconnected: OSM's topology is explicit, so OSM imports
do not node crossings.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from pathlib import Path

import osmium

from ingest.network.file_reader import NetworkFileError
from ingest.network.model import Coord, NodePoint, RoadAttributes, RoadLine
from ingest.network.osm_tags import (
    EXTERNAL_ID_TAG,
    attributes_from_tags,
    is_road,
    osm_external_id,
)

TRAFFIC_SIGNALS = "traffic_signals"


def read_osm(path: Path) -> Iterator[RoadLine | NodePoint]:
    """Every road way as RoadLines (coordinates resolved), and node attributes: traffic
    lights, and nodes our own OSM export tagged with their ``external_id``. A generator: each
    call reads the file again, so a country-sized extract is never held in memory (only ways
    over new, negative-id nodes wait for one more pass: see :class:`NewNodes`)."""
    new_nodes = NewNodes()
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
                                    external_id=named or osm_external_id("n", obj.id))
                continue
            assert isinstance(obj, osmium.osm.Way)  # the processor yields only nodes and ways
            tags = dict(obj.tags)
            if not is_road(tags):
                continue
            attributes = attributes_from_tags(tags, external_id=osm_external_id("w", obj.id))
            coords = [(n.lon, n.lat) if n.location.valid() else None for n in obj.nodes]
            if not new_nodes.defer([n.ref for n in obj.nodes], coords, attributes):
                yield from _lines(coords, attributes)
        for coords, attributes in new_nodes.resolve(path):
            yield from _lines(coords, attributes)
    except RuntimeError as exc:  # libosmium reports parse errors as RuntimeError
        raise NetworkFileError(f"{path.name}: {_unreadable(exc)}") from exc


def _unreadable(exc: RuntimeError) -> str:
    """What libosmium's parse error means for the file, in our words."""
    xml = re.search(r"XML parsing error at line (\d+), column (\d+)", str(exc))
    if xml:
        return (f"not OpenStreetMap XML: it is not well-formed XML (line {xml[1]}, column "
                f"{xml[2]})")
    if str(exc).startswith("PBF error"):
        return ("not an OpenStreetMap PBF file: its blocks cannot be read (the file is cut "
                "short, corrupt, or not PBF)")
    return f"not a readable OpenStreetMap file ({exc})"


def _lines(coords: list[Coord | None], attributes: RoadAttributes) -> Iterator[RoadLine]:
    """The way's located runs of two or more vertices, as road lines."""
    for run in _located_runs(coords):
        if len(run) > 1:
            yield RoadLine(run, attributes)


class NewNodes:
    """Ways over nodes with negative ids: objects not (yet) in OSM, as JOSM saves them and as
    our export writes every object. libosmium's location index keeps positive ids only, so
    such ways wait until one more pass over the file's nodes has found those locations."""

    def __init__(self) -> None:
        self._ways: list[tuple[list[int], list[Coord | None], RoadAttributes]] = []
        self._wanted: set[int] = set()

    def defer(self, refs: list[int], coords: list[Coord | None],
              attributes: RoadAttributes) -> bool:
        """Keep a way for :meth:`resolve` if it misses the location of a new node."""
        missing = {ref for ref, c in zip(refs, coords, strict=True) if c is None and ref < 0}
        if missing:
            self._ways.append((refs, coords, attributes))
            self._wanted |= missing
        return bool(missing)

    def resolve(self, path: Path) -> Iterator[tuple[list[Coord | None], RoadAttributes]]:
        """The kept ways with their new nodes located (one pass over the nodes, only if any
        way was kept)."""
        if not self._ways:
            return
        found: dict[int, Coord] = {}
        for node in osmium.FileProcessor(str(path), osmium.osm.NODE):
            assert isinstance(node, osmium.osm.Node)  # the processor yields only nodes
            if node.id < 0 and node.id in self._wanted and node.location.valid():
                found[node.id] = (node.location.lon, node.location.lat)
        for refs, coords, attributes in self._ways:
            yield [c if c is not None else found.get(ref)
                   for ref, c in zip(refs, coords, strict=True)], attributes


def _located_runs(coords: Iterable[Coord | None]) -> list[list[Coord]]:
    """Split a way where node locations are missing (ways cut by the extract boundary), so
    no straight line is drawn across the gap."""
    runs: list[list[Coord]] = [[]]
    for c in coords:
        if c is not None:
            runs[-1].append(c)
        elif runs[-1]:
            runs.append([])
    return runs
