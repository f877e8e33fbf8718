"""Export a network (or the part meeting a bbox) as a Lanelet2 map file, with the
``map_projector_info.yaml`` Autoware reads beside it.

Shared by ``ugvmap export network --format lanelet2``, the HTTP endpoint and the offline
mission package. The map's origin (``--origin``, else the centre of the exported segments'
bounds rounded to 1e-4°) is written in three places: the projector file, the file's header
comment, and implicitly in every node's ``local_x``/``local_y``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from sqlalchemy import Connection

from app.errors import InvalidParameterValueError, UserError
from app.lanelet2.build import MapSummary, Progress, write_map
from app.lanelet2.frame import Frame
from app.lanelet2.geometry import standard_utm_zone
from app.lanelet2.osm_xml import OsmXmlWriter
from app.lanelet2.roads import NetworkSelection, NodeTable, read_selection
from app.lanelet2.topology import Defect
from app.network.ogc_params import parse_bbox
from app.terrain.heights import ground

Bbox = tuple[float, float, float, float]
UTM_LATITUDES = (-80.0, 84.0)
FORMAT_VERSION = "1.0"
MAX_DEFECTS_IN_FILE = 200
PROJECTOR_FILE = "map_projector_info.yaml"


def parse_area(value: str | None) -> Bbox | None:
    """``W,S,E,N`` in degrees for an export: finite, within lon/lat range, west < east and
    south < north (an area, not a line; no antimeridian crossing)."""
    box = parse_bbox(value)
    if box is None:
        return None
    w, s, e, n = box
    if not (-180 <= w < e <= 180 and -90 <= s < n <= 90):
        raise InvalidParameterValueError(
            "bbox must be W,S,E,N with -180 <= W < E <= 180 and -90 <= S < N <= 90")
    return box


def parse_origin(value: str | None) -> tuple[float, float] | None:
    """``LAT,LON`` of a map origin (as lanelet2's ``Origin`` takes them)."""
    if value is None:
        return None
    try:
        lat, lon = (float(v) for v in value.split(","))
    except ValueError:
        raise UserError(f"origin must be LAT,LON in degrees, not {value[:40]!r}") from None
    if not (math.isfinite(lat) and math.isfinite(lon) and -180 <= lon <= 180):
        raise UserError("origin must be finite, with longitude -180..180")
    _check_latitude(lat, "origin")
    return lat, lon


def _check_latitude(lat: float, what: str) -> None:
    if not UTM_LATITUDES[0] <= lat <= UTM_LATITUDES[1]:
        raise UserError(f"{what} latitude {lat:.4f} is outside UTM's 80°S..84°N: a Lanelet2 "
                        "export is built in the UTM zone of its origin")


def within_utm(sel: NetworkSelection) -> tuple[NetworkSelection, list[Defect]]:
    """``sel`` without the segments UTM cannot hold (a vertex south of 80°S or north of
    84°N), each reported as a defect: one such segment (an edit sent in EPSG:32701 reaches
    there) made the whole network's export fail for everyone."""
    roads = sel.roads
    lat = roads.lonlat[:, 1]
    outside = (lat < UTM_LATITUDES[0]) | (lat > UTM_LATITUDES[1])
    if not outside.any():
        return sel, []
    bad = np.zeros(len(roads), bool)
    bad[np.repeat(np.arange(len(roads)), np.diff(roads.offsets))[outside]] = True
    defects = [Defect(int(i), "outside-utm", "a vertex lies outside UTM's 80°S..84°N: "
                      "not mapped") for i in roads.ids[bad]]
    kept, _ = roads.take(np.flatnonzero(~bad))
    ends = np.isin(sel.nodes.ids, np.concatenate([kept.source, kept.target]))
    nodes = NodeTable(sel.nodes.ids[ends], sel.nodes.lonlat[ends], sel.nodes.traffic_light[ends])
    return replace(sel, roads=kept, nodes=nodes), defects


def default_origin(lonlat: np.ndarray) -> tuple[float, float]:
    """(lat, lon) of the centre of the points' bounds, rounded to 1e-4° (~10 m) so small edits
    do not move every coordinate of the map."""
    lo, hi = lonlat.min(axis=0), lonlat.max(axis=0)
    return round(float(lo[1] + hi[1]) / 2, 4), round(float(lo[0] + hi[0]) / 2, 4)


def projector_info(origin: tuple[float, float]) -> str:
    """Autoware's ``map_projector_info.yaml``: local Cartesian UTM around the origin, the
    frame the map's ``local_x``/``local_y`` are in."""
    return ("projector_type: LocalCartesianUTM\nvertical_datum: WGS84\nmap_origin:\n"
            f"  latitude: {origin[0]}\n  longitude: {origin[1]}\n  altitude: 0.0\n")


@dataclass(frozen=True)
class Lanelet2Export:
    """What an export wrote and where the map's origin is."""

    network: str
    version: int
    path: Path
    origin: tuple[float, float]
    utm_zone: int
    summary: MapSummary


def _comment(sel: NetworkSelection, origin: tuple[float, float], zone: int,
             summary: MapSummary) -> str:
    summary_defects = [str(d) for d in summary.defects]
    lat, lon = origin
    area = f" within bbox {','.join(map(str, sel.bbox))}" if sel.bbox else ""
    lines = [f"ugvmap Lanelet2 map of network {sel.name} version {sel.version}{area}.",
             f"Origin lat {lat} lon {lon} (UTM zone {zone}): load with "
             f"lanelet2.io.load(path, lanelet2.projection.UtmProjector(lanelet2.io.Origin("
             f"{lat}, {lon}))); Autoware: {PROJECTOR_FILE} with projector_type "
             "LocalCartesianUTM and this map_origin. local_x/local_y are metres in that frame.",
             f"{len(summary_defects)} degenerate segments handled by the documented rules"
             + (":" if summary_defects else ".")]
    lines += summary_defects[:MAX_DEFECTS_IN_FILE]
    if len(summary_defects) > MAX_DEFECTS_IN_FILE:
        lines.append(f"... and {len(summary_defects) - MAX_DEFECTS_IN_FILE} more")
    dropped = summary.movements_dropped
    lines.append(f"{len(dropped)} junction movements not drawn (the roads overlap where they "
                 "meet)" + (":" if dropped else "."))
    lines += [f"node {n}: segment {a} to segment {b}" for n, a, b in
              dropped[:MAX_DEFECTS_IN_FILE]]
    return "\n".join(lines)


def write_lanelet2(sel: NetworkSelection, out: Path, origin: tuple[float, float] | None = None,
                   progress: Progress | None = None,
                   ground: Callable[[np.ndarray], np.ndarray] | None = None) -> Lanelet2Export:
    """Write the map of ``sel`` to ``out`` (complete or not at all) and its projector file
    beside it (named as Autoware's map loader expects); ``ground``: heights at lon/lat rows
    for the nodes' ``ele`` (an elevation layer's, :func:`app.terrain.heights.ground`)."""
    if not out.parent.is_dir():
        raise UserError(f"{out.parent} is not a directory")
    if not len(sel.roads):
        where = f" within bbox {','.join(map(str, sel.bbox))}" if sel.bbox else ""
        raise UserError(f"network {sel.name!r} has no segments{where}: nothing to map")
    sel, outside = within_utm(sel)
    if not len(sel.roads):
        raise UserError(f"every segment of network {sel.name!r} to map has a vertex outside "
                        "UTM's 80°S..84°N: nothing a Lanelet2 map can hold")
    origin = origin or default_origin(sel.roads.lonlat)
    zone = standard_utm_zone(origin[1], origin[0])
    epsg = (32600 if origin[0] >= 0 else 32700) + zone
    frame = Frame(epsg, (origin[1], origin[0]))
    lo, hi = sel.roads.lonlat.min(axis=0), sel.roads.lonlat.max(axis=0)
    meta = {"format_version": FORMAT_VERSION, "map_version": f"{sel.name}@{sel.version}"}
    # The defects are only known once the map is planned, but the comment heads the file:
    # the writer assembles the header at close, so it is set after the map is written.
    writer = OsmXmlWriter(out, comment="", meta=meta, bounds=(lo[0], lo[1], hi[0], hi[1]),
                          ground=ground)
    try:
        summary = write_map(sel, frame, writer, progress)
        summary.defects = outside + summary.defects
        writer.set_comment(_comment(sel, origin, zone, summary))
        writer.close()
    except BaseException:
        writer.discard()
        raise
    (out.parent / PROJECTOR_FILE).write_text(projector_info(origin), encoding="utf-8")
    return Lanelet2Export(sel.name, sel.version, out, origin, zone, summary)


def export_lanelet2(conn: Connection, network: str, out: Path, *, bbox: Bbox | None = None,
                    origin: tuple[float, float] | None = None,
                    progress: Progress | None = None,
                    elevation_layer: str | None = None) -> Lanelet2Export:
    """Read network ``network`` (the segments meeting ``bbox``, whole) and write its map,
    with ``ele`` from ``elevation_layer`` where it has heights (else 0)."""
    heights = ground(conn, elevation_layer) if elevation_layer else None
    if progress:
        progress("reading the network", 0.0)
    return write_lanelet2(read_selection(conn, network, bbox), out, origin, progress, heights)
