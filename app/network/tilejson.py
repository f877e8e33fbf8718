"""What a vector-tile client needs to use a network's tiles without being told: TileJSON 3.0.0
with ``vector_layers``, a MapLibre style, and the MBTiles-style ``metadata.json`` GDAL's MVT
driver reads. Pure builders over one description of the tile layers (:data:`TILE_LAYERS`).

The tile SQL lives in :mod:`app.network.tiles`; ``tests/test_network_discovery.py`` decodes a
real tile and checks its layers and fields are exactly the ones described here.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from app.network.collections import Kind
from app.network.properties import GEOMETRY, MVT_TYPES, by_name
from app.network.tiles import LANES_MINZOOM, NODES_MINZOOM

MINZOOM = 0
# Past this zoom clients overzoom: a z18 tile's 4096-unit grid is already ~4 cm.
MAXZOOM = 18
OTHER_COLOUR = "#5a6b7a"
# Road class -> line colour (the class and its *_link share one), in legend order.
# Unclassified is white: every extracted road starts unclassified, and white on the dark
# casing stands out over any imagery (the slate of "other" was faint over asphalt and soil).
ROAD_CLASS_COLOURS = (
    ("motorway", "#e8308a"), ("trunk", "#f0642a"), ("primary", "#f5a623"),
    ("secondary", "#e6d23c"), ("tertiary", "#8fd14f"), ("residential", "#4fb5d1"),
    ("service", "#9b8fd1"), ("track", "#a0764a"), ("unclassified", "#ffffff"),
)
CASING_COLOUR = "#1d2329"
# Ways for people, not vehicles (the classes the car profile never drives that carry no
# traffic at all): drawn thin and sand-coloured with a faint rim, so a city's footway mesh
# (Helsinki at z15) does not look like a grid of streets.
PATH_CLASSES = ("footway", "cycleway", "path", "pedestrian", "steps", "bridleway", "corridor")
PATH_COLOUR = "#e0cfa6"
PATH_WIDTH_SHARE = 0.35  # of a road's width at the same zoom


@dataclass(frozen=True)
class TileLayer:
    """One layer of the network's vector tiles."""

    id: str
    kind: Kind
    fields: tuple[str, ...]
    minzoom: int
    description: str


TILE_LAYERS = (
    TileLayer("segments", "segments",
              ("name", "road_class", "oneway", "lanes_forward", "lanes_backward",
               "speed_limit_kph", "is_junction", "surface", "width_m", "length_m", "version",
               "confidence"),
              MINZOOM, "Road segments (feature id = segment id); simplified below z14; "
                       "confidence only where the segment was extracted from imagery"),
    TileLayer("nodes", "nodes", ("kind", "traffic_light"), NODES_MINZOOM,
              "Topology nodes (feature id = node id)"),
    TileLayer("lanes", "lanes",
              ("segment_id", "kind", "colour", "position", "source", "width_m", "confidence",
               "version"),
              LANES_MINZOOM, "Lane boundaries from the paint (feature id = boundary id): "
                             "kind solid/dashed/solid_solid/road_edge/stop_line/crosswalk/other, "
                             "source paint or offset (no paint there)"),
)
# Lane boundaries by kind: (style layer id, filter, dash pattern or None). One layer per
# kind with fixed paint values, for QGIS's style converter (see NODE_STYLES); the colour of
# the paint (yellow where yellow, else white), guessed (offset) lines faint.
LANE_STYLES: tuple[tuple[str, list[Any], list[float] | None], ...] = (
    ("lanes-solid", ["match", ["get", "kind"], ["solid", "solid_solid", "road_edge"], True,
                     False], None),
    ("lanes-dashed", ["==", ["get", "kind"], "dashed"], [3, 3]),
    ("lanes-stop", ["==", ["get", "kind"], "stop_line"], None),
    ("lanes-crosswalk", ["==", ["get", "kind"], "crosswalk"], [0.5, 0.5]),
)
LANE_WIDTH = ["interpolate", ["linear"], ["zoom"], 16, 1.0, 20, 3.0]


@dataclass(frozen=True)
class NetworkInfo:
    """What the builders need to know about a network."""

    name: str
    title: str | None
    description: str | None
    version: int
    bounds: list[float] | None


def vector_layers() -> list[dict[str, Any]]:
    """TileJSON ``vector_layers``: each layer's fields with their types, and its zooms."""
    return [{"id": layer.id, "description": layer.description,
             "fields": {f: MVT_TYPES[by_name(layer.kind)[f].type] for f in layer.fields},
             "minzoom": layer.minzoom, "maxzoom": MAXZOOM} for layer in TILE_LAYERS]


def _bounds(network: NetworkInfo) -> list[float]:
    return network.bounds or [-180.0, -85.0511, 180.0, 85.0511]


def _center(network: NetworkInfo) -> list[float]:
    b = _bounds(network)
    return [(b[0] + b[2]) / 2, (b[1] + b[3]) / 2, 14]


def tilejson(network: NetworkInfo, tiles_url: str) -> dict[str, Any]:
    """TileJSON 3.0.0 for the network's tiles (``tiles_url`` is the {z}/{x}/{y} template)."""
    return {
        "tilejson": "3.0.0",
        "name": network.title or network.name,
        "description": network.description or f"ugvmap road network {network.name}",
        "version": f"1.0.{network.version}",
        "attribution": "",
        "scheme": "xyz",
        "tiles": [tiles_url],
        "minzoom": MINZOOM,
        "maxzoom": MAXZOOM,
        "bounds": _bounds(network),
        "center": _center(network),
        "vector_layers": vector_layers(),
    }


def _class_colour() -> list[Any]:
    expression: list[Any] = ["match", ["get", "road_class"]]
    for cls, colour in ROAD_CLASS_COLOURS:
        expression += [[cls, f"{cls}_link"], colour]
    return [*expression, list(PATH_CLASSES), PATH_COLOUR, OTHER_COLOUR]


# Nodes by what they are: (style layer id, filter, colour, radius, stroke width, min zoom).
# One style layer per kind with fixed paint values, not one layer with data-driven ``case``
# expressions: QGIS's MapLibre style converter (QgsMapBoxGlStyleConverter) understands a
# layer ``filter`` and fixed values but drops ``case``/``step`` paint expressions, which drew
# junctions and traffic lights alike in QGIS. Plain nodes and junctions only from z16: at z15
# a city's footways made a junction dot every few pixels (issue 34); traffic lights from z12.
NODE_STYLES: tuple[tuple[str, list[Any], str, float, float, int], ...] = (
    ("nodes", ["all", ["!=", ["get", "traffic_light"], True],
               ["!=", ["get", "kind"], "junction"]], "#607080", 2.5, 1, 16),
    ("nodes-junctions", ["all", ["!=", ["get", "traffic_light"], True],
                         ["==", ["get", "kind"], "junction"]], "#ff9800", 4, 1, 16),
    ("nodes-traffic-lights", ["==", ["get", "traffic_light"], True], "#e02020", 6, 2,
     NODES_MINZOOM),
)


def _line_width(extra: float) -> list[Any]:
    """Line width by zoom, ``extra`` pixels wider (a casing is the line plus a rim); ways of
    :data:`PATH_CLASSES` a fraction of a road's width (with a one-pixel rim)."""
    stops: list[Any] = []
    for zoom, road in ((10, 1.5), (16, 5.0), (19, 10.0)):
        path = round(road * PATH_WIDTH_SHARE, 2) + min(extra, 1.0)
        stops += [zoom, ["match", ["get", "road_class"], list(PATH_CLASSES), path,
                         road + extra]]
    return ["interpolate", ["linear"], ["zoom"], *stops]


def style(network: NetworkInfo, tilejson_url: str) -> dict[str, Any]:
    """A MapLibre style drawing the network: roads coloured by class over a dark casing (so a
    road of any colour shows over imagery), junctions orange, traffic lights red (plain nodes
    from z16), painted lane boundaries from z16 (dashed where dashed, yellow where yellow),
    in constructs QGIS's style converter keeps (:data:`NODE_STYLES`). No glyphs or
    sprites, so it loads offline."""
    source = network.name
    line = {"line-cap": "round", "line-join": "round"}
    return {
        "version": 8,
        "name": f"ugvmap network {network.name}",
        "center": _center(network)[:2],
        "zoom": _center(network)[2],
        "sources": {source: {"type": "vector", "url": tilejson_url}},
        "layers": [
            {"id": "segments-casing", "type": "line", "source": source,
             "source-layer": "segments", "layout": line,
             "paint": {"line-color": CASING_COLOUR,
                       "line-opacity": ["match", ["get", "road_class"], list(PATH_CLASSES),
                                        0.4, 0.85],
                       "line-width": _line_width(2.5)}},
            {"id": "segments", "type": "line", "source": source, "source-layer": "segments",
             "layout": line, "paint": {"line-color": _class_colour(),
                                       "line-width": _line_width(0)}},
            *({"id": layer_id, "type": "circle", "source": source, "source-layer": "nodes",
               "minzoom": minzoom, "filter": node_filter,
               "paint": {"circle-color": colour, "circle-radius": radius,
                         "circle-stroke-width": stroke, "circle-stroke-color": "#ffffff"}}
              for layer_id, node_filter, colour, radius, stroke, minzoom in NODE_STYLES),
            *({"id": layer_id, "type": "line", "source": source, "source-layer": "lanes",
               "minzoom": LANES_MINZOOM, "filter": lane_filter,
               "paint": {"line-color": ["match", ["get", "colour"], "yellow", "#ffd400",
                                        "#ffffff"],
                         "line-opacity": ["match", ["get", "source"], "offset", 0.45, 1.0],
                         "line-width": LANE_WIDTH if layer_id != "lanes-stop" else 3.0,
                         **({"line-dasharray": dash} if dash else {})}}
              for layer_id, lane_filter, dash in LANE_STYLES),
        ],
    }


def mbtiles_metadata(network: NetworkInfo,
                     integer_ranges: dict[str, tuple[int, int]]) -> dict[str, Any]:
    """``metadata.json`` as MBTiles writes it (strings, layers in a ``json`` string), which
    GDAL's MVT driver reads next to a tile directory. ``tilestats`` gives each layer's
    geometry type and the integer fields' ranges, so GDAL types them Integer, not Real."""
    layers = []
    for layer in TILE_LAYERS:
        attributes = [{"attribute": f, "type": "number", "min": low, "max": high}
                      for f, (low, high) in integer_ranges.items() if f in layer.fields]
        layers.append({"layer": layer.id, "geometry": GEOMETRY[layer.kind],
                       "attributeCount": len(layer.fields), "attributes": attributes})
    bounds, center = _bounds(network), _center(network)
    return {
        "name": network.title or network.name,
        "description": network.description or f"ugvmap road network {network.name}",
        "version": str(network.version),
        "format": "pbf",
        "type": "overlay",
        "minzoom": str(MINZOOM),
        "maxzoom": str(MAXZOOM),
        "bounds": ",".join(f"{v:.7f}" for v in bounds),
        "center": ",".join(f"{v:.7f}" for v in center[:2]) + f",{center[2]}",
        "json": json.dumps({"vector_layers": vector_layers(),
                            "tilestats": {"layerCount": len(layers), "layers": layers}}),
    }
