"""Read road lines (and node attributes) from GeoJSON and GeoPackage files.

Line features become RoadLines; Point features carry node attributes (``traffic_light``,
``external_id``) matched to nodes by location. A file whose every line names its
``source_node`` and ``target_node`` (our own exports do) already is a topology: it is imported
as it is, without noding crossings, so a bridge exported as unconnected stays unconnected.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyogrio
import pyproj
import shapely

from app.errors import UserError
from ingest.network.model import NodePoint, RoadLine
from ingest.network.properties import as_bool, as_road_lines


class NetworkFileError(UserError):
    """The file cannot be read as a road network; the message says why."""


def _node_point(geometry: Mapping[str, Any], props: Mapping[str, Any]) -> NodePoint:
    x, y = geometry["coordinates"][:2]
    external = props.get("external_id")
    return NodePoint((float(x), float(y)), traffic_light=as_bool(props.get("traffic_light")),
                     external_id=None if external is None else str(external))


def split_features(features: Iterable[Mapping[str, Any]]
                   ) -> tuple[list[RoadLine], list[NodePoint], bool]:
    """GeoJSON-like features -> (lines, node points, whether the lines carry a topology)."""
    lines: list[RoadLine] = []
    points: list[NodePoint] = []
    topological = True
    for number, feature in enumerate(features, start=1):
        geometry = feature.get("geometry") or {}
        props = feature.get("properties") or {}
        try:
            if geometry.get("type") == "Point":
                points.append(_node_point(geometry, props))
                continue
            lines.extend(as_road_lines({"type": "Feature", "geometry": geometry,
                                        "properties": props}))
        except (ValueError, TypeError, KeyError, IndexError) as exc:
            raise NetworkFileError(f"feature {number}: {exc}") from exc
        topological &= props.get("source_node") is not None and \
            props.get("target_node") is not None
    return lines, points, topological and bool(lines)


def nodes_file(path: Path) -> Path | None:
    """``x.segments.geojson`` -> ``x.nodes.geojson`` when it exists: the node attributes our
    GeoJSON export writes beside the segments."""
    stem, dot, ext = path.name.rpartition(".")
    if not stem.endswith(".segments"):
        return None
    sibling = path.with_name(f"{stem.removesuffix('.segments')}.nodes{dot}{ext}")
    return sibling if sibling.is_file() else None


def _geojson_features(path: Path) -> list[dict[str, Any]] | None:
    """The features of a GeoJSON file in lon/lat; None for a legacy projected ``crs``."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise NetworkFileError(f"{path.name}: not a GeoJSON file: it is not JSON (line "
                               f"{exc.lineno}, column {exc.colno})") from exc
    except UnicodeDecodeError as exc:
        raise NetworkFileError(f"{path.name}: not a GeoJSON file: it is not UTF-8 text "
                               f"(byte {exc.start})") from exc
    except OSError as exc:
        raise NetworkFileError(f"{path.name}: cannot be read ({exc.strerror})") from exc
    crs_name = ((data.get("crs") or {}).get("properties") or {}).get("name")
    if crs_name and not _is_lonlat(crs_name):
        return None
    if data.get("type") == "FeatureCollection":
        return data.get("features") or []
    if data.get("type") == "Feature":
        return [data]
    return [{"type": "Feature", "geometry": data, "properties": {}}]


def read_geojson(path: Path) -> tuple[list[RoadLine], list[NodePoint], bool]:
    """Lines, node attributes and whether the file is already a topology (names
    ``source_node``/``target_node``: our exports, not to be noded again). Points of the
    file's :func:`nodes_file`, if any, are node attributes too."""
    features = _geojson_features(path)
    if features is None:
        return read_ogr(path)  # legacy GeoJSON in a projected CRS: let GDAL reproject
    lines, points, topological = split_features(features)
    sibling = nodes_file(path)
    if sibling is not None:
        node_lines, node_points, _ = split_features(_geojson_features(sibling) or [])
        if node_lines:
            raise NetworkFileError(f"{sibling.name}: a nodes file must hold only Points")
        points += node_points
    if not lines and points and path.name.rpartition(".")[0].endswith(".nodes"):
        segments = path.name.replace(".nodes.", ".segments.")
        raise NetworkFileError(f"{path.name} holds only the nodes: import {segments}")
    return lines, points, topological


def _clean(value: Any) -> Any:
    if isinstance(value, float) and math.isnan(value):
        return None
    return value.item() if hasattr(value, "item") else value


WGS84 = pyproj.CRS.from_epsg(4326)


def _is_lonlat(crs: str) -> bool:
    try:
        parsed = pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError as exc:
        raise NetworkFileError(f"unknown CRS {crs[:100]!r}") from exc
    return parsed.equals(WGS84, ignore_axis_order=True)


def _to_lonlat(geoms: np.ndarray, crs: str | None) -> np.ndarray:
    """Reproject to lon/lat (EPSG:4326) unless the layer already is (or names no CRS)."""
    if crs is None or _is_lonlat(crs):
        return geoms
    transformer = pyproj.Transformer.from_crs(crs, WGS84, always_xy=True)
    return shapely.transform(geoms, lambda xy: np.column_stack(
        transformer.transform(xy[:, 0], xy[:, 1])))


def _ogr_features(path: Path, layer: str) -> list[dict[str, Any]]:
    meta, _, wkb, columns = pyogrio.raw.read(path, layer=layer)
    names = list(meta["fields"])
    features = []
    for i, geom in enumerate(_to_lonlat(shapely.from_wkb(wkb), meta.get("crs"))):
        props = {name: _clean(col[i]) for name, col in zip(names, columns, strict=True)}
        features.append({"type": "Feature", "geometry": shapely.geometry.mapping(geom),
                         "properties": props})
    return features


NETWORK_FORMATS = ("OpenStreetMap (.osm, .osm.pbf), GeoJSON, GeoPackage or another vector "
                   "format GDAL reads")


def _unopenable(exc: Exception) -> str:
    """Why GDAL could not open a network file, in our words (not its advice to prefix the
    path with a driver name)."""
    if "not recognized as being in a supported file format" in str(exc):
        return f"not a road network file: its content is in none of {NETWORK_FORMATS}"
    return f"a damaged vector file: GDAL cannot open it (expected {NETWORK_FORMATS})"


def read_ogr(path: Path) -> tuple[list[RoadLine], list[NodePoint], bool]:
    """Every layer of a GeoPackage (or any OGR vector file): lines and node points, in
    lon/lat whatever the layer's CRS."""
    try:
        layers = pyogrio.list_layers(path)
    except Exception as exc:  # pyogrio raises its own DataSourceError hierarchy
        raise NetworkFileError(f"{path.name}: {_unopenable(exc)}") from exc
    features: list[dict[str, Any]] = []
    for name, geometry_type in layers:
        if geometry_type and ("Line" in geometry_type or "Point" in geometry_type):
            features.extend(_ogr_features(path, name))
    return split_features(features)
