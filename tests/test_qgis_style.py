"""The network style read the way QGIS's style converter reads it
(:mod:`tests.qgis_style`): junctions, traffic lights and plain nodes keep distinct colours
and sizes in QGIS, drawn from the node features of a real vector tile."""

from __future__ import annotations

import mapbox_vector_tile
import morecantile

from testkit.network_helpers import bearer, grid_network
from tests.qgis_style import circle_styles

# The node layer the style had before: one layer, colour and size by ``case`` (and ``step``
# on zoom), which MapLibre draws and QGIS's converter drops.
BEFORE = {"layers": [{"id": "nodes", "type": "circle", "source-layer": "nodes", "minzoom": 14,
                      "paint": {"circle-color": ["case", ["get", "traffic_light"], "#e02020",
                                                 ["==", ["get", "kind"], "junction"],
                                                 "#ff9800", "#607080"],
                                "circle-radius": ["step", ["zoom"], 4, 16, 2.5]}}]}


def _drawn(styles, props: dict, zoom: float) -> list[tuple[str, float]]:
    """(colour, radius) of every style QGIS draws the node with."""
    return [(s.colour, s.radius) for s in styles
            if s.source_layer == "nodes" and s.draws(props, zoom)]


def test_qgis_keeps_the_node_colours(client) -> None:
    net = grid_network()
    nodes = f"/collections/{net.network}-nodes/items"
    centre = next(f["id"] for f in client.get(nodes).json()["features"]
                  if f["geometry"]["coordinates"] == [10.001, 50.001])
    assert client.patch(f"{nodes}/{centre}", json={"traffic_light": True},
                        headers=bearer("editor")).status_code == 200
    tile = morecantile.tms.get("WebMercatorQuad").tile(10.001, 50.001, 16)
    mvt = client.get(f"/networks/{net.network}/tiles/16/{tile.x}/{tile.y}.mvt")
    features = mapbox_vector_tile.decode(mvt.content)["nodes"]["features"]
    by_kind = {("light" if f["properties"].get("traffic_light") else f["properties"]["kind"]):
               f["properties"] for f in features}
    assert {"light", "junction", "node"} <= set(by_kind)

    styles = circle_styles(client.get(f"/networks/{net.network}/style.json").json())
    assert [w for s in styles for w in s.warnings] == []
    light = _drawn(styles, by_kind["light"], 17)
    junction = _drawn(styles, by_kind["junction"], 17)
    plain = _drawn(styles, by_kind["node"], 17)
    assert len(light) == len(junction) == len(plain) == 1  # each drawn once
    assert light[0][0] == "#e02020" and junction[0][0] == "#ff9800"
    assert len({light[0], junction[0], plain[0]}) == 3 and light[0][1] > junction[0][1]
    assert _drawn(styles, by_kind["node"], 15) == []  # plain nodes from z16 only
    assert _drawn(styles, by_kind["junction"], 15) == []  # junctions too (a city at z15)
    assert _drawn(styles, by_kind["light"], 15) == light  # traffic lights from z12

    # The old style: QGIS skips both expressions and draws every node alike.
    old = circle_styles(BEFORE)
    assert len(old[0].warnings) == 2
    assert _drawn(old, by_kind["light"], 15) == _drawn(old, by_kind["junction"], 15)
