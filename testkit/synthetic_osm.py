"""A country-sized road network written as an OSM PBF, reproducibly, from a seed.

No real extract of a million segments ships with the project and nothing may be downloaded,
so the scale benchmark and tests generate one. It goes through the real importer
(``ugvmap ingest network x.osm.pbf``) like any OSM file. The shape is a perturbed grid with
what a real network has and a plain lattice lacks:

- a class hierarchy: every 120th row/column is a motorway, every 60th a trunk, 20th primary,
  10th secondary, 5th tertiary, the rest residential (so low-zoom tiles have something to
  filter and time costs vary by road, as in OSM);
- random deletions of minor streets (dead ends, T-junctions and through nodes, so degrees are
  spread over 1..4 rather than all 4), diagonal links across some blocks, short service spurs;
- jittered node positions, curved streets (a shape vertex on half of the edges), one-way
  residential streets, ``maxspeed`` on part of the main roads, traffic signals on main
  junctions;
- ways that span several blocks, so the importer must split them at shared nodes.

``python -m testkit.synthetic_osm --side 810 --out country.osm.pbf`` (810 x 810
intersections: 1.01M segments once imported, a 97 km square; ~1.54 segments per
intersection at any side).
"""

from __future__ import annotations

import argparse
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import osmium

METRES_PER_DEG_LAT = 111_320.0
# (period, class, max edges per way): a row/column whose index is a multiple of the period
LEVELS = ((120, "motorway", 40), (60, "trunk", 40), (20, "primary", 30),
          (10, "secondary", 20), (5, "tertiary", 15))
MINOR = ("residential", 6)
MINOR_DELETE = 0.28  # share of residential grid edges removed
DIAGONAL_SHARE = 0.03  # blocks crossed by a diagonal street
SPUR_SHARE = 0.04  # intersections with a service spur into the block
ONEWAY_SHARE = 0.1  # residential ways that are one-way
SIGNAL_SHARE = 0.3  # junctions of two main roads with traffic signals
MAXSPEED = {"motorway": ("130", "110"), "trunk": ("100", "80"), "primary": ("70", "50"),
            "secondary": ("50",), "tertiary": ("50", "30")}


@dataclass(frozen=True)
class CountryShape:
    """What was written, for logs and tests."""

    side: int
    nodes: int
    ways: int
    grid_edges: int


def road_class(index: int) -> tuple[str, int]:
    """Class and longest way (in edges) of grid row/column ``index``."""
    for period, cls, longest in LEVELS:
        if index % period == 0:
            return cls, longest
    return MINOR


def _tags(cls: str, rng: np.random.Generator, way_no: int) -> dict[str, str]:
    tags = {"highway": cls, "name": f"{cls.title()} {way_no}"}
    if cls in MAXSPEED and rng.random() < 0.5:
        tags["maxspeed"] = str(rng.choice(MAXSPEED[cls]))
    if cls in ("motorway", "trunk"):
        tags["lanes"] = "2"
    if cls == "residential" and rng.random() < ONEWAY_SHARE:
        tags["oneway"] = "yes" if rng.random() < 0.5 else "-1"
    return tags


def write_country(out: Path, side: int, *, spacing_m: float = 120.0,
                  origin: tuple[float, float] = (10.0, 50.0), seed: int = 0) -> CountryShape:
    """Write the network of ``side`` x ``side`` intersections to ``out`` (.osm.pbf)."""
    rng = np.random.default_rng(seed)
    lon0, lat0 = origin
    dlat = spacing_m / METRES_PER_DEG_LAT
    dlon = spacing_m / (METRES_PER_DEG_LAT * math.cos(math.radians(lat0)))
    jitter = 0.12  # of the spacing
    rows, cols = np.divmod(np.arange(side * side), side)
    lon = lon0 + (cols + rng.uniform(-jitter, jitter, side * side)) * dlon
    lat = lat0 + (rows + rng.uniform(-jitter, jitter, side * side)) * dlat
    node_id = np.arange(1, side * side + 1)  # grid node (r, c) is r * side + c + 1
    next_id = side * side + 1
    shape_nodes: list[tuple[int, float, float]] = []
    ways: list[tuple[list[int], dict[str, str]]] = []
    used = np.zeros(side * side, bool)
    grid_edges = 0

    def shape_point(a: int, b: int) -> int:
        """A vertex between grid nodes a and b, pushed sideways: a curved street."""
        nonlocal next_id
        bend = rng.uniform(-0.08, 0.08)
        x = (lon[a] + lon[b]) / 2 + bend * (lat[b] - lat[a]) * dlon / dlat
        y = (lat[a] + lat[b]) / 2 - bend * (lon[b] - lon[a]) * dlat / dlon
        shape_nodes.append((next_id, float(x), float(y)))
        next_id += 1
        return next_id - 1

    def emit(run: list[int], cls: str) -> None:
        nonlocal grid_edges
        refs = [int(node_id[run[0]])]
        for a, b in itertools.pairwise(run):
            if rng.random() < 0.5:
                refs.append(shape_point(a, b))
            refs.append(int(node_id[b]))
        used[run] = True
        grid_edges += len(run) - 1
        ways.append((refs, _tags(cls, rng, len(ways) + 1)))

    for axis in (0, 1):  # rows, then columns
        for line in range(side):
            cls, longest = road_class(line)
            cells = (line * side + np.arange(side)) if axis == 0 else (np.arange(side) * side
                                                                       + line)
            keep = np.ones(side - 1, bool)
            if cls == MINOR[0]:
                keep = rng.random(side - 1) >= MINOR_DELETE
            run = [int(cells[0])]
            for k in range(side - 1):
                if keep[k] and len(run) <= longest:
                    run.append(int(cells[k + 1]))
                    continue
                if len(run) > 1:
                    emit(run, cls)
                run = [int(cells[k + 1])] if not keep[k] else [int(cells[k]), int(cells[k + 1])]
            if len(run) > 1:
                emit(run, cls)

    blocks = np.flatnonzero(rng.random((side - 1) * (side - 1)) < DIAGONAL_SHARE)
    for b in blocks.tolist():
        r, c = divmod(b, side - 1)
        a, d = (r * side + c, (r + 1) * side + c + 1) if rng.random() < 0.5 else \
            (r * side + c + 1, (r + 1) * side + c)
        emit([a, d], "residential")
    for n in np.flatnonzero(used & (rng.random(side * side) < SPUR_SHARE)).tolist():
        tip = next_id
        shape_nodes.append((tip, float(lon[n] + 0.35 * dlon), float(lat[n] + 0.3 * dlat)))
        next_id += 1
        ways.append(([int(node_id[n]), tip], {"highway": "service"}))

    signals = _main_junctions(side, rng)
    _write_pbf(out, node_id[used], lon[used], lat[used], signals, shape_nodes, ways)
    return CountryShape(side, int(used.sum()) + len(shape_nodes), len(ways), grid_edges)


def _main_junctions(side: int, rng: np.random.Generator) -> set[int]:
    """Grid node ids where two main roads (tertiary or above) cross, some with signals."""
    main = np.arange(0, side, LEVELS[-1][0])
    r, c = np.meshgrid(main, main, indexing="ij")
    ids = (r * side + c + 1).ravel()
    return set(ids[rng.random(len(ids)) < SIGNAL_SHARE].tolist())


def _write_pbf(out: Path, ids: np.ndarray, lon: np.ndarray, lat: np.ndarray, signals: set[int],
               shape_nodes: list[tuple[int, float, float]],
               ways: list[tuple[list[int], dict[str, str]]]) -> None:
    out.unlink(missing_ok=True)
    writer = osmium.SimpleWriter(str(out))
    try:
        node = osmium.osm.mutable.Node
        for i, x, y in zip(ids.tolist(), lon.tolist(), lat.tolist(), strict=True):
            tags = {"highway": "traffic_signals"} if i in signals else {}
            writer.add_node(node(id=i, location=(x, y), tags=tags))
        for i, x, y in shape_nodes:
            writer.add_node(node(id=i, location=(x, y)))
        for number, (refs, tags) in enumerate(ways, start=1):
            writer.add_way(osmium.osm.mutable.Way(id=number, nodes=refs, tags=tags))
    finally:
        writer.close()


def write_ways(out: Path, ways: Sequence[tuple[dict[str, str], Sequence[tuple[float, float]]]]
               ) -> None:
    """A small hand-drawn OSM file (``.osm`` or ``.osm.pbf`` by ``out``'s suffix): each way
    is its tags and its lon/lat vertices; ways meet where they share a vertex (one OSM node
    per distinct coordinate), as mapped ways do."""
    node_of: dict[tuple[float, float], int] = {}
    refs = [([node_of.setdefault(p, len(node_of) + 1) for p in points], tags)
            for tags, points in ways]
    lon, lat = (np.array([p[k] for p in node_of]) for k in (0, 1))
    _write_pbf(out, np.array(list(node_of.values())), lon, lat, set(), [], refs)


def main() -> None:
    """Command line: write the synthetic country to a PBF file."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--side", type=int, default=810,
                    help="intersections per side (810 -> 1.01M segments)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    shape = write_country(args.out, args.side, seed=args.seed)
    print(f"{args.out}: {shape.nodes} nodes, {shape.ways} ways, {shape.grid_edges} grid edges")


if __name__ == "__main__":
    main()
