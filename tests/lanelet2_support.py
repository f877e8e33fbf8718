"""Helpers of the Lanelet2 tests: export a stored network, load it with the official lanelet2
library (never with a reader of ours), and compare its routes with ugvmap's."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from lanelet2 import geometry, io, projection, routing, traffic_rules

from app.lanelet2.export import PROJECTOR_FILE, Lanelet2Export, export_lanelet2
from app.lanelet2.roads import snapshot


@dataclass
class LoadedMap:
    """A map as lanelet2 loads it, with Autoware's routing graph (German vehicle rules)."""

    map: Any
    rules: Any
    graph: Any
    origin: tuple[float, float]

    def lanelets(self) -> list[Any]:
        return list(self.map.laneletLayer)

    def by_segment(self) -> dict[tuple[int, str], list[Any]]:
        """Lanelets of each (segment id, direction), rightmost lane first; junction lanelets
        under (segment they leave, "junction")."""
        out: dict[tuple[int, str], list[Any]] = defaultdict(list)
        for ll in self.map.laneletLayer:
            a = ll.attributes
            kind = a["direction"] if "direction" in a else "junction"  # noqa: SIM401 (no .get)
            out[int(a["segment_id"]), kind].append(ll)
        for key in out:
            out[key].sort(key=lambda ll: int(ll.attributes["lane"]) if "lane" in ll.attributes
                          else 0)
        return dict(out)


def load(path: Path) -> LoadedMap:
    """Load ``path`` with the origin its projector file names; the load must report no error
    and the routing graph must pass lanelet2's own validity check."""
    info = yaml.safe_load((path.parent / PROJECTOR_FILE).read_text())
    origin = (info["map_origin"]["latitude"], info["map_origin"]["longitude"])
    assert info["projector_type"] == "LocalCartesianUTM"
    lanelet_map, errors = io.loadRobust(str(path), projection.UtmProjector(io.Origin(*origin)))
    assert errors == [], errors[:5]
    rules = traffic_rules.create(traffic_rules.Locations.Germany,
                                 traffic_rules.Participants.Vehicle)
    graph = routing.RoutingGraph(lanelet_map, rules)
    assert graph.checkValidity(False) == []
    assert_as_written(lanelet_map)
    return LoadedMap(lanelet_map, rules, graph, origin)


def assert_as_written(lanelet_map: Any) -> None:
    """lanelet2 read every lanelet the way we wrote it: the loader turns a lanelet's bounds
    round to fit its heuristic, so a forward or junction lanelet must keep both bounds as
    written and a backward one must have both turned (they are written along the geometry).
    One bound turned alone would break the lanelet's successors."""
    wrong = []
    for ll in lanelet_map.laneletLayer:
        a = ll.attributes
        turned = "direction" in a and a["direction"] == "backward"
        if (ll.leftBound.inverted(), ll.rightBound.inverted()) != (turned, turned):
            wrong.append((ll.id, a["segment_id"]))
    assert wrong == [], wrong[:10]


def export(name: str, out: Path, **kw: Any) -> tuple[Lanelet2Export, LoadedMap]:
    with snapshot() as conn:
        result = export_lanelet2(conn, name, out, **kw)
    return result, load(out)


def path_length(path: Any) -> float:
    """Metres driven along a lanelet path from the middle of its first lanelet to the middle
    of its last; a lane change moves sideways instead of driving the lanelet it leaves."""
    driven = [ll for ll, nxt in zip(path, [*path[1:], None], strict=True)
              if nxt is None or not _same_road(ll, nxt)]
    lengths = [geometry.length2d(ll) for ll in driven]
    return sum(lengths) - lengths[0] / 2 - lengths[-1] / 2


def _same_road(a: Any, b: Any) -> bool:
    pa, pb = a.attributes, b.attributes
    return ("direction" in pa and "direction" in pb and pa["segment_id"] == pb["segment_id"]
            and pa["direction"] == pb["direction"])


def lanelet_route(m: LoadedMap, lanes: dict[tuple[int, str], list[Any]], a: int, b: int
                  ) -> tuple[float, list[int]] | None:
    """The shortest lanelet route from segment ``a`` to ``b`` (either direction of each, the
    rightmost lane), as (metres from the middle of a to the middle of b, segment ids)."""
    best = None
    for da in ("forward", "backward"):
        for db in ("forward", "backward"):
            if (a, da) not in lanes or (b, db) not in lanes:
                continue
            found = m.graph.shortestPath(lanes[a, da][0], lanes[b, db][0])
            if found is None:
                continue
            length = path_length(list(found))
            if best is None or length < best[0]:
                segs = [int(ll.attributes["segment_id"]) for ll in found]
                best = (length, [s for i, s in enumerate(segs) if i == 0 or segs[i - 1] != s])
    return best


def ugvmap_route(client: Any, name: str, a: tuple[float, float], b: tuple[float, float]
                 ) -> tuple[float, list[int]] | None:
    """ugvmap's shortest route by distance between two points, or None for NoRoute."""
    r = client.get(f"/networks/{name}/route", params={
        "points": f"{a[0]!r},{a[1]!r};{b[0]!r},{b[1]!r}", "cost": "distance",
        "steps": "false", "overview": "false", "radius": "5"})
    if r.status_code == 422 and r.json()["code"] == "NoRoute":
        return None
    assert r.status_code == 200, r.text
    body = r.json()
    segs = [s["id"] for leg in body["routes"][0]["legs"] for s in leg["segments"]]
    return body["routes"][0]["distance"], [s for i, s in enumerate(segs)
                                           if i == 0 or segs[i - 1] != s]
