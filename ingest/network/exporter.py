"""Export a stored network as GeoJSON, GeoPackage or OSM XML/PBF.

Every format carries enough to rebuild the same network: segment geometries in their
digitising direction with every attribute, and node attributes (traffic lights, external ids).
Segments and nodes are kept apart, as clients expect one geometry type per layer: two
GeoJSON files (``x.segments.geojson`` with LineStrings, ``x.nodes.geojson`` with Points, which
the importer reads back as one network) and two GeoPackage layers. GeoJSON and GeoPackage
also carry ``source_node``/``target_node``, which tells the importer the file is already a
topology. OSM files follow the convention for objects not (yet) in OSM, which JOSM and
osmium expect: negative ids and no ``version``. OSM stores coordinates at 1e-7 degrees, so an
OSM round trip is exact for networks that came from OSM and accurate to ~1 cm otherwise.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import osmium
import pyogrio
import shapely
from sqlalchemy import text
from sqlalchemy.orm import Session

from app.errors import UserError
from ingest.network.model import ATTRIBUTE_NAMES, Coord, RoadAttributes
from ingest.network.osm_tags import EXTERNAL_ID_TAG, tags_from_attributes

FORMATS = ("geojson", "gpkg", "osm")


@dataclass
class StoredSegment:
    """A stored segment with everything an export must write for the re-import to be identical."""
    id: int
    source_node: int
    target_node: int
    length_m: float
    version: int
    coords: list[Coord]
    attributes: RoadAttributes


@dataclass
class StoredNode:
    """A stored node with the attributes an export keeps."""
    id: int
    coord: Coord
    kind: str
    traffic_light: bool
    external_id: str | None


def load_network(session: Session, network: str,
                 bbox: tuple[float, float, float, float] | None = None
                 ) -> tuple[list[StoredSegment], list[StoredNode]]:
    """The network's segments and nodes, ordered by id so exports are deterministic; with
    ``bbox`` (W, S, E, N) only the segments meeting it, whole, and the nodes they end at."""
    network_id = session.execute(text("SELECT id FROM networks WHERE name = :n"),
                                 {"n": network}).scalar()
    if network_id is None:
        raise UserError(f"network {network[:100]!r} does not exist")
    area = ("" if bbox is None else
            " AND ST_Intersects(geom, ST_MakeEnvelope(:w, :s, :e, :nn, 4326))")
    params = {"n": network_id, **({} if bbox is None else dict(zip(("w", "s", "e", "nn"), bbox,
                                                                    strict=True)))}
    rows = session.execute(text(
        f"SELECT id, source_node, target_node, length_m, version, {', '.join(ATTRIBUTE_NAMES)}, "
        "ST_AsGeoJSON(geom, 17) AS geometry FROM road_segments WHERE network_id = :n"
        f"{area} ORDER BY id"), params).all()
    segments = [StoredSegment(
        r.id, r.source_node, r.target_node, r.length_m, r.version,
        [tuple(c) for c in json.loads(r.geometry)["coordinates"]],
        RoadAttributes(**{k: getattr(r, k) for k in ATTRIBUTE_NAMES})) for r in rows]
    ends = (None if bbox is None else
            sorted({s.source_node for s in segments} | {s.target_node for s in segments}))
    nodes = [StoredNode(r.id, tuple(json.loads(r.geometry)["coordinates"]), r.kind,
                        r.traffic_light, r.external_id)
             for r in session.execute(text(
                 "SELECT id, kind, traffic_light, external_id, ST_AsGeoJSON(geom, 17) AS geometry "
                 "FROM road_nodes WHERE network_id = :n"
                 + ("" if ends is None else " AND id = ANY(CAST(:ends AS bigint[]))")
                 + " ORDER BY id"), {"n": network_id, "ends": ends})]
    return segments, nodes


def _segment_properties(s: StoredSegment) -> dict[str, Any]:
    return {"id": s.id, "source_node": s.source_node, "target_node": s.target_node,
            "length_m": s.length_m, "version": s.version, **asdict(s.attributes)}


def _node_properties(n: StoredNode) -> dict[str, Any]:
    return {"id": n.id, "kind": n.kind, "traffic_light": n.traffic_light,
            "external_id": n.external_id}


def geojson_paths(out: Path) -> tuple[Path, Path]:
    """``x.geojson`` (or ``x.segments.geojson``) -> (``x.segments.geojson``,
    ``x.nodes.geojson``): the two files a GeoJSON export writes."""
    stem = out.name
    for suffix in (".geojson", ".json", ".segments", ".nodes"):
        stem = stem.removesuffix(suffix)
    ext = ".json" if out.name.endswith(".json") else ".geojson"
    return out.with_name(f"{stem}.segments{ext}"), out.with_name(f"{stem}.nodes{ext}")


def _feature_collection(path: Path, features: list[dict[str, Any]]) -> None:
    path.write_text(json.dumps({"type": "FeatureCollection", "features": features},
                               ensure_ascii=False), encoding="utf-8")


def segment_features(segments: list[StoredSegment]) -> list[dict[str, Any]]:
    """Segments as LineString features whose properties name the topology, so import keeps
    it as is."""
    return [{"type": "Feature", "id": s.id, "properties": _segment_properties(s),
             "geometry": {"type": "LineString", "coordinates": s.coords}} for s in segments]


def node_features(nodes: list[StoredNode]) -> list[dict[str, Any]]:
    """Nodes as Point features with their attributes."""
    return [{"type": "Feature", "id": n.id, "properties": _node_properties(n),
             "geometry": {"type": "Point", "coordinates": n.coord}} for n in nodes]


def _columns(rows: list[dict[str, Any]]) -> tuple[list[str], list[np.ndarray]]:
    """Property dicts -> OGR field arrays: floats with NaN for null, objects for text."""
    names = list(rows[0])
    arrays = []
    for name in names:
        values = [r[name] for r in rows]
        sample = next((v for v in values if v is not None), "")
        if isinstance(sample, bool):
            arrays.append(np.array(values, dtype=bool))
        elif isinstance(sample, int) and None not in values:
            arrays.append(np.array(values, dtype=np.int64))
        elif isinstance(sample, int | float):
            arrays.append(np.array([np.nan if v is None else v for v in values], dtype=float))
        else:
            arrays.append(np.array(values, dtype=object))
    return names, arrays


def write_gpkg(path: Path, segments: list[StoredSegment], nodes: list[StoredNode]) -> None:
    """Two layers, ``segments`` and ``nodes``; ``attrs`` as JSON text (GeoPackage has no
    object type)."""
    layers = [
        ("segments", "LineString", [shapely.LineString(s.coords) for s in segments],
         [{**_segment_properties(s), "attrs": json.dumps(s.attributes.attrs,
                                                         ensure_ascii=False)}
          for s in segments]),
        ("nodes", "Point", [shapely.Point(n.coord) for n in nodes],
         [_node_properties(n) for n in nodes]),
    ]
    for layer, geometry_type, geoms, rows in layers:
        if not rows:
            continue
        names, arrays = _columns(rows)
        pyogrio.raw.write(path, shapely.to_wkb(np.array(geoms, dtype=object)), arrays,
                          fields=names, layer=layer, driver="GPKG", geometry_type=geometry_type,
                          crs="EPSG:4326", append=path.exists())


def write_osm(path: Path, segments: list[StoredSegment], nodes: list[StoredNode]) -> None:
    """New OSM objects: network nodes are -1..-n, interior vertices count on down from there,
    ways (one per segment) are -1..-m, and nothing has a version (libosmium writes none for
    version 0)."""
    node_ids = {n.coord: -i for i, n in enumerate(nodes, start=1)}
    next_id = -len(nodes) - 1
    vertices: dict[Coord, int] = {}
    ways = []
    for way_id, s in enumerate(segments, start=1):
        refs = []
        for c in s.coords:
            if c in node_ids:
                refs.append(node_ids[c])
                continue
            if c not in vertices:
                vertices[c], next_id = next_id, next_id - 1
            refs.append(vertices[c])
        ways.append((-way_id, refs, tags_from_attributes(s.attributes)))
    if path.exists():
        path.unlink()
    writer = osmium.SimpleWriter(str(path))
    try:
        for n in nodes:
            tags = {"highway": "traffic_signals"} if n.traffic_light else {}
            if n.external_id is not None:
                tags[EXTERNAL_ID_TAG] = n.external_id
            writer.add_node(osmium.osm.mutable.Node(id=node_ids[n.coord], location=n.coord,
                                                    tags=tags))
        for coord, vid in vertices.items():
            writer.add_node(osmium.osm.mutable.Node(id=vid, location=coord))
        for wid, refs, tags in ways:
            writer.add_way(osmium.osm.mutable.Way(id=wid, nodes=refs, tags=tags))
    finally:
        writer.close()


@dataclass(frozen=True)
class ExportSummary:
    """What an export wrote."""

    segments: int
    nodes: int
    files: list[Path]


def _write_atomically(path: Path, write: Callable[[Path], None], fmt: str) -> None:
    """Write ``path`` under a temporary name and rename it: it appears complete or not at all.
    The temporary name keeps the suffix (GDAL and osmium choose the format by it)."""
    suffix = "".join(path.suffixes) or {"geojson": ".geojson", "gpkg": ".gpkg",
                                        "osm": ".osm"}[fmt]
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp{suffix}")
    try:
        write(tmp)
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


def export_network(session: Session, network: str, out: Path, fmt: str,
                   bbox: tuple[float, float, float, float] | None = None) -> ExportSummary:
    """Write network ``network`` (with ``bbox``: the segments meeting it, whole) to ``out``
    (GeoJSON: the two files of :func:`geojson_paths`, the nodes first, so the segments file,
    which import starts from, appears last)."""
    if fmt not in FORMATS:
        raise UserError(f"format must be one of {', '.join(FORMATS)}")
    segments, nodes = load_network(session, network, bbox)
    if not segments and bbox is not None:
        raise UserError(f"network {network[:100]!r} has no segments within bbox "
                        f"{','.join(map(str, bbox))}")
    outputs: list[tuple[Path, Callable[[Path], None]]]
    if fmt == "geojson":
        segment_path, node_path = geojson_paths(out)
        outputs = [(node_path, lambda p: _feature_collection(p, node_features(nodes))),
                   (segment_path, lambda p: _feature_collection(p, segment_features(segments)))]
    elif fmt == "gpkg":
        outputs = [(out, lambda p: write_gpkg(p, segments, nodes))]
    else:
        outputs = [(out, lambda p: write_osm(p, segments, nodes))]
    for path, write in outputs:
        _write_atomically(path, write, fmt)
    return ExportSummary(len(segments), len(nodes), [path for path, _ in outputs])
