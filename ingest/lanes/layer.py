"""``ugvmap ingest lanes``: a raster layer's lane markings, read where a network's roads are,
stored as each segment's lanes and lane boundaries.

Only the imagery around the network's segments is read (each connected area of the layer's
sources, windowed to the segments' bounds plus the reach of a cut), and nothing coarser than
0.2 m/px is read at all. Markings are measured in the UTM zone of the segments (metres, not
web-mercator's stretched ones), assigned to the nearest segment, cut into lanes and
boundaries by :mod:`ingest.lanes.assign`, and written in the caller's transaction: the rows
of every segment with paint are replaced at once, so a failure leaves the old ones. The
segment's own lane counts (what routing reads) follow its longest lane range, unless a person
edited the segment.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import rasterio
import shapely
from pyproj import CRS, Transformer
from shapely.geometry import box
from sqlalchemy import text
from sqlalchemy.orm import Session

from app.lanelet2.geometry import standard_utm_zone
from app.lanelet2.topology import lanes_fit
from app.network import collections as colls
from app.network.editing import lock_feature, write_change
from app.network.resurvey.changes import LANES_FROM_PAINT, MACHINE_ACTIONS
from app.network.tokens import Principal
from app.tiles.catalog import get_layer
from app.tiles.store import open_store
from ingest.lanes import LanesInputError, check_resolution
from ingest.lanes.assign import REACH_M, Boundary, LaneRange, Paint, boundaries, lane_ranges
from ingest.lanes.extract import extract_markings
from ingest.roads.layer import LayerSource, layer_mosaic, source_areas

Progress = Callable[[float, str], None]
MACHINE = "ingest-lanes"
"""Who wrote the rows ``ingest lanes`` writes (``updated_by``, ``edited_by``)."""

SEGMENTS_SQL = """
SELECT s.id, ST_AsBinary(s.geom)
  FROM road_segments s
 WHERE s.network_id = :net AND EXISTS (
       SELECT 1 FROM raster_sources r
        WHERE r.layer_id = :layer AND ST_Intersects(r.footprint, ST_Transform(s.geom, 3857)))
 ORDER BY s.id
"""


@dataclass
class LanesIngest:
    """What ``ingest lanes`` read and stored."""

    layer: str
    network: str
    segments: int = 0
    """Segments of the network over the layer's imagery."""
    markings: int = 0
    laned: list[int] = field(default_factory=list)
    """Segments with lanes from the paint (their rows replaced)."""
    ranges: list[LaneRange] = field(default_factory=list)
    rows: list[Boundary] = field(default_factory=list)
    recounted: list[int] = field(default_factory=list)
    """Segments whose lane counts were set from the paint."""
    kept: list[int] = field(default_factory=list)
    """Segments whose lanes a person edited: left as they are."""

    def lines(self) -> list[str]:
        """The CLI's report."""
        paint = sum(b.source == "paint" and b.position is not None for b in self.rows)
        guessed = sum(b.source == "offset" for b in self.rows)
        stops = sum(b.kind == "stop_line" for b in self.rows)
        crossings = sum(b.kind == "crosswalk" for b in self.rows)
        counts = sorted({f"{r.forward}+{r.backward}" for r in self.ranges})
        tapers = sum(r.taper is not None for r in self.ranges)
        return [f"network {self.network}: lanes from the paint of layer {self.layer} on "
                f"{len(self.laned)} of {self.segments} segments ({self.markings} markings "
                f"found)",
                f"{len(self.ranges)} lane ranges ({', '.join(counts) or 'none'} lanes "
                f"forward+backward, {tapers} opening or ending along a painted taper), "
                f"{paint} painted boundary stretches, {guessed} offset where no paint, "
                f"{stops} stop lines, {crossings} crossings",
                f"lane counts of {len(self.recounted)} segments set from the paint (segments a "
                f"person edited keep theirs)"] + (
            [f"{len(self.kept)} segments keep the lanes a person edited: "
             f"{', '.join(map(str, self.kept[:20]))}"] if self.kept else [])


def _layer(session: Session, slug: str) -> tuple[int, list[LayerSource]]:
    layer = get_layer(session.connection(), slug)
    if layer is None:
        raise LanesInputError(f"no raster layer {slug!r} (see `ugvmap layers list`)")
    if layer["kind"] == "elevation":
        raise LanesInputError(f"layer {slug!r} holds heights (an elevation layer), not imagery")
    if not layer["sources"]:
        raise LanesInputError(f"layer {slug!r} has no sources")
    finest = min((s["resolution_m"] for s in layer["sources"] if s["resolution_m"]),
                 default=layer["resolution_m"])
    if finest is not None:
        try:
            check_resolution(float(finest))
        except LanesInputError as exc:
            raise LanesInputError(f"layer {slug!r}: {exc}") from None
    store = open_store()
    return int(layer["id"]), [LayerSource(s["name"], store.resolve(s["uri"]))
                              for s in reversed(layer["sources"])]


def _segments(session: Session, network: str, layer_id: int, slug: str
              ) -> tuple[int, np.ndarray, list[shapely.LineString]]:
    net = session.execute(text("SELECT id FROM networks WHERE name = :n"),
                          {"n": network}).scalar()
    if net is None:
        raise LanesInputError(f"network {network!r} does not exist (see `ugvmap network list`)")
    rows = session.execute(text(SEGMENTS_SQL), {"net": net, "layer": layer_id}).all()
    if not rows:
        raise LanesInputError(f"network {network!r} has no road over layer {slug!r}'s "
                              "imagery: nothing to read lanes for")
    return (int(net), np.array([r[0] for r in rows], np.int64),
            [shapely.from_wkb(bytes(r[1])) for r in rows])


def _area_paint(area: list[LayerSource], roads_3857: shapely.Geometry,
                to_metric: Transformer) -> list[Paint]:
    """The markings of one connected area of the layer, in the window around the roads."""
    footprints = []
    for source in area:
        with rasterio.open(source.path) as dataset:
            footprints.append(box(*dataset.bounds))
    bounds = shapely.union_all(footprints)
    window = shapely.intersection(bounds, roads_3857.buffer(3 * REACH_M).envelope)
    if window.is_empty:
        return []
    image = layer_mosaic([s.path for s in area], [s.name for s in area], window.bounds)
    assert image.transform is not None
    out = []
    for m in extract_markings(image):
        xs, ys = image.transform @ (m.coords[:, 0], m.coords[:, 1])
        x, y = to_metric.transform(np.asarray(xs), np.asarray(ys))
        out.append(Paint(shapely.LineString(np.column_stack([x, y])), m.kind, m.colour,
                         m.width_m, m.confidence))
    return out


def ingest_layer_lanes(session: Session, slug: str, network: str,
                       progress: Progress | None = None) -> LanesIngest:
    """Read layer ``slug``'s lane markings where network ``network``'s segments are and store
    each segment's lanes and boundaries in the caller's transaction."""
    say: Progress = progress or (lambda _f, _m: None)
    layer_id, sources = _layer(session, slug)
    net_id, ids, lines = _segments(session, network, layer_id, slug)
    done = LanesIngest(slug, network, segments=len(ids))
    centre = shapely.union_all(lines).centroid
    metric = CRS.from_epsg((32600 if centre.y >= 0 else 32700)
                           + standard_utm_zone(centre.x, centre.y))
    to_metric = Transformer.from_crs("EPSG:3857", metric, always_xy=True)
    lonlat_to_metric = Transformer.from_crs("EPSG:4326", metric, always_xy=True)
    to_lonlat = Transformer.from_crs(metric, "EPSG:4326", always_xy=True)
    roads_3857 = shapely.transform(shapely.union_all(lines), Transformer.from_crs(
        "EPSG:4326", "EPSG:3857", always_xy=True).transform, interleaved=False)
    paint: list[Paint] = []
    areas = source_areas(sources)
    for i, area in enumerate(areas):
        say(0.05 + 0.6 * i / len(areas), f"reading the markings of area {i + 1}/{len(areas)}")
        paint += _area_paint(area, roads_3857, to_metric)
    done.markings = len(paint)
    refs = [shapely.transform(line, lonlat_to_metric.transform, interleaved=False)
            for line in lines]
    tree = shapely.STRtree([p.line for p in paint])
    seg_tree = shapely.STRtree(refs)
    written: list[tuple[int, list[LaneRange], list[Boundary]]] = []
    done.kept = _edited_lanes(session, net_id, ids)
    for j, (sid, ref) in enumerate(zip(ids.tolist(), refs, strict=True)):
        say(0.65 + 0.3 * j / len(refs), f"lanes of segment {sid}")
        if sid in done.kept:
            continue
        near = [paint[k] for k in tree.query(ref, predicate="dwithin", distance=REACH_M)]
        ranges = lane_ranges(ref, near)
        if not ranges:
            continue
        others = [refs[k] for k in seg_tree.query(ref, predicate="dwithin",
                                                  distance=2 * REACH_M) if k != j]
        rows = boundaries(ref, near, ranges, shapely.union_all(others) if others else None)
        written.append((sid, ranges, rows))
        done.ranges += ranges
        done.rows += rows
    say(0.95, f"storing the lanes of {len(written)} segments")
    _store(session, net_id, written, to_lonlat)
    done.laned = [sid for sid, _, _ in written]
    done.recounted = _recount(session, colls.Collection(network, net_id, "segments"), written)
    return done


def _edited_lanes(session: Session, net_id: int, ids: np.ndarray) -> list[int]:
    """The segments whose lane boundaries a person edited or deleted, or whose lane ranges a
    person set (``PUT .../lanes``): a re-run keeps them (human edits are never overwritten;
    delete the boundaries, and PUT an empty list of ranges, to read the paint again)."""
    return sorted(session.execute(text(
        "SELECT segment_id FROM lane_boundaries WHERE segment_id = ANY(:ids) "
        "AND updated_by IS DISTINCT FROM :machine UNION "
        "SELECT (old->>'segment_id')::bigint FROM lane_boundary_edits WHERE network_id = :net "
        "AND action = 'delete' AND (old->>'segment_id')::bigint = ANY(:ids) UNION "
        "SELECT segment_id FROM segment_lanes WHERE segment_id = ANY(:ids) "
        "AND source = 'edited'"),
        {"ids": ids.tolist(), "machine": MACHINE, "net": net_id}).scalars())


def _recount(session: Session, c: colls.Collection,
             written: list[tuple[int, list[LaneRange], list[Boundary]]]) -> list[int]:
    """Set each segment's ``lanes_forward``/``lanes_backward`` (what routing reads) to the
    lanes of its longest range, as a new version with a history row (action
    ``lanes-from-paint``, revertable); not on a segment a person edited (their counts win),
    nor where the paint's counts do not fit its one-way rule (a two-way road whose line
    between the directions went unseen reads as all lanes one way). Returns those changed."""
    ids = [sid for sid, _, _ in written]
    edited: set[int] = set(session.execute(text(
        "SELECT DISTINCT segment_id FROM segment_edits WHERE segment_id = ANY(:ids) "
        "AND action <> ALL(:machine)"), {"ids": ids, "machine": list(MACHINE_ACTIONS)}
    ).scalars())
    machine = Principal(MACHINE, "editor")
    changed = []
    for sid, ranges, _ in written:
        if sid in edited:
            continue
        main = max(ranges, key=lambda r: r.station_to_m - r.station_from_m)
        feature = lock_feature(session, c, sid, None)
        new = {"lanes_forward": main.forward, "lanes_backward": main.backward}
        if not lanes_fit(feature["properties"]["oneway"], main.forward, main.backward):
            continue
        if write_change(session, c, feature, new, machine, LANES_FROM_PAINT) is not feature:
            changed.append(sid)
    return changed


def _store(session: Session, net_id: int,
           written: list[tuple[int, list[LaneRange], list[Boundary]]],
           to_lonlat: Transformer) -> None:
    """Replace the lanes and boundaries of the segments in ``written``."""
    ids = [sid for sid, _, _ in written]
    if not ids:
        return
    session.execute(text("DELETE FROM lane_boundaries WHERE segment_id = ANY(:ids)"),
                    {"ids": ids})
    session.execute(text("DELETE FROM segment_lanes WHERE segment_id = ANY(:ids)"),
                    {"ids": ids})
    lanes = [{"net": net_id, "seg": sid, "lo": r.station_from_m, "hi": r.station_to_m,
              "f": r.forward, "b": r.backward, "w": r.widths, "o": list(r.offsets),
              "c": r.confidence} for sid, ranges, _ in written for r in ranges]
    session.execute(text(
        "INSERT INTO segment_lanes (network_id, segment_id, station_from_m, station_to_m, "
        "lanes_forward, lanes_backward, widths_m, offsets_m, confidence) "
        "VALUES (:net, :seg, :lo, :hi, :f, :b, :w, :o, :c)"), lanes)
    rows = [{"net": net_id, "seg": sid,
             "wkt": shapely.transform(b.line, to_lonlat.transform, interleaved=False).wkt,
             "kind": b.kind, "colour": b.colour, "width": b.width_m,
             "conf": round(min(max(b.confidence, 0.0), 1.0), 3), "pos": b.position,
             "off": b.offset_m, "lo": b.station_from_m, "hi": b.station_to_m,
             "src": b.source, "machine": MACHINE}
            for sid, _, found in written for b in found]
    if rows:
        session.execute(text(
            "INSERT INTO lane_boundaries (network_id, segment_id, geom, kind, colour, width_m, "
            "confidence, position, offset_m, station_from_m, station_to_m, source, updated_by) "
            "VALUES (:net, :seg, ST_GeomFromText(:wkt, 4326), :kind, :colour, :width, :conf, "
            ":pos, :off, :lo, :hi, :src, :machine)"),
            rows)
