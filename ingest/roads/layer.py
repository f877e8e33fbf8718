"""``ugvmap ingest roads``: extract the road network of a stored raster layer into PostGIS.

The layer's sources are merged (top source first, masks honoured) into one image in memory,
so overlapping zones are extracted once rather than per file (which would store every road
twice where zones overlap); its valid mask is the sources' own coverage, so nothing is drawn
where no source has data. Only sources that overlap or touch are merged: a layer's connected
areas (two surveys far apart) are extracted one after the other, each its own mosaic, since
one mosaic over their common bounding box would be mostly empty and, for areas a continent
apart, far beyond memory. Training samples are given in map coordinates (lon/lat boxes,
or road centerlines from a vector file) because a layer has no pixel grid a user could point
at; they are burnt into the label image on the mosaic's grid, on valid pixels only.

An ``ipm-mosaic`` layer made by ``ugvmap ingest ipm`` knows where the vehicle drove
(``layer_trajectories``): without a sample, that trajectory is the road sample (one lane wide
around it: the vehicle drove there; the road goes on past the drive's first and last pose), so
``auto`` fits the road's colour to the drive's own imagery with no hand labels
(:data:`IPM_CLASSIFIER`). The mosaic goes to the pipeline at its own resolution with its
coverage as the valid mask: the pipeline refines centrelines on such fine grids and never
bridges no-data. The extracted graph gets its attributes from the rules of
:mod:`ingest.roads.attributes` (defaults < network settings < job options) and goes through
the network importer's ``write_network``, so it obeys the same topology rules as any imported
file.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import rasterio
from pyproj import CRS, Transformer
from rasterio.enums import ColorInterp
from rasterio.merge import merge
from shapely.geometry import box
from sqlalchemy.orm import Session

from app.network.resurvey.changes import coverage_of_layer
from app.network.resurvey.matching import Tolerances
from app.network.settings import AttributeRules
from app.road_tuning import Classifier
from app.tiles.catalog import get_layer
from app.tiles.store import open_store
from ingest.ipm.trajectory import layer_trajectories
from ingest.network import ImportSummary, RoadAttributes, RoadLine, write_network
from ingest.network.osm_tags import BOTH_WAYS_TAG
from ingest.network.update import update_from_lines
from ingest.raster.footprint import connected_areas
from ingest.roads import RoadsInputError
from ingest.roads.attributes import segment_attributes
from ingest.roads.classify import ROAD
from ingest.roads.georef import Image, as_image, pixel_size_m
from ingest.roads.pipeline import Extraction, ExtractParams, extract_roads
from ingest.roads.rules import effective_rules
from ingest.roads.sample import NO_SAMPLE_ROAD, GeoSample, LonLatBox, burn_sample
from ingest.roads.taught import Taught, merged, taught

MAX_MOSAIC_SIDE_PX = 40_000
MAX_MOSAIC_PX = MAX_MOSAIC_SIDE_PX ** 2
"""Refuse an area whose mosaic would not fit a 2-core / 24 GiB machine's memory."""
IPM_CLASSIFIER: Classifier = "spectral"
"""What ``auto`` means on an ipm-mosaic layer. A drive's lane is a clean sample of the road
surface's colour, and a mosaic seen from the road shows little else that is grey. Measured
again with the centrelines refined on the mosaic's own grid (which takes the road's edges
from the mosaic's colours whichever classifier found the road): on the 189-frame ring of
``bench/ipm_roads.py`` spectral gives median / p95 / max 0.033 / 0.110 / 0.161 m in 2.7 s,
the road model adapted to the drive 0.034 / 0.124 / 0.250 m in 8.9 s, learned 0.037 / 0.136
/ 0.222 m in 9.3 s; on the 36-frame test drive spectral 0.059 / 0.141 / 0.174 m, adapted
0.063 / 0.212 / 0.241 m; with 18 frames lost only spectral finds the road at all (roads-v1
and the roads-v2 snapshot alike; zero-shot finds none of these drives). So spectral stays:
as accurate or better, and 3x faster."""
TRAJECTORY_WIDTH_M = 3.0
"""Road sample width around a drive's trajectory: one lane (the vehicle drove in a lane; a
wider band would call the verge of a narrow road "road")."""


def layer_mosaic(paths: Sequence[str], names: Sequence[str] | None = None,
                 bounds: tuple[float, float, float, float] | None = None) -> Image:
    """The mosaic of ``paths`` (all EPSG:3857, the one drawn on top first) at the finest
    source resolution, merged in memory, valid where any source has data (their own masks,
    whatever the pixel values: a black pixel of a JPEG COG is data). ``names`` (the sources'
    names, for the error of a mosaic too large) default to the paths. ``bounds`` (EPSG:3857
    left, bottom, right, top): only that window, read from the COGs without the rest (a
    preview of the view on the map)."""
    datasets = [rasterio.open(p) for p in paths]
    try:
        res = min(min(abs(d.res[0]), abs(d.res[1])) for d in datasets)
        left, bottom, right, top = bounds or (
            min(d.bounds.left for d in datasets), min(d.bounds.bottom for d in datasets),
            max(d.bounds.right for d in datasets), max(d.bounds.top for d in datasets))
        width, height = round((right - left) / res), round((top - bottom) / res)
        if width * height > MAX_MOSAIC_PX:
            raise RoadsInputError(
                f"the area of {', '.join(names or paths)} would be one {width:,} x {height:,} px "
                f"mosaic at its finest source resolution, more than the {MAX_MOSAIC_SIDE_PX:,} x "
                f"{MAX_MOSAIC_SIDE_PX:,} px one extraction holds in memory; extract its "
                "source images one by one with `ugvmap extract-roads`")
        colour = [i for i, c in enumerate(datasets[0].colorinterp, 1)
                  if c != ColorInterp.alpha] or [1]
        pixels, transform = merge(datasets, bounds=bounds, res=res, indexes=colour, nodata=0)
        count, _ = merge(datasets, bounds=bounds, res=res, indexes=[1], nodata=0,
                         dtype="uint16", method="count")
        crs = CRS.from_user_input(datasets[0].crs)
    finally:
        for d in datasets:
            d.close()
    resolution = pixel_size_m(transform, crs, pixels.shape[1:])
    return as_image(pixels, count[0] > 0, transform, crs, resolution)


@dataclass(frozen=True)
class LayerSource:
    """One of a layer's sources as extraction reads it: its name and its COG's local path."""

    name: str
    path: str


def source_areas(sources: Sequence[LayerSource]) -> list[list[LayerSource]]:
    """The sources grouped by the connected areas their bounds cover: overlapping or touching
    sources in one group (kept in the sources' order, top first, as ``merge`` needs), the
    groups in the order of their first source."""
    bounds = []
    for source in sources:
        with rasterio.open(source.path) as dataset:
            bounds.append(box(*dataset.bounds))
    member = connected_areas(bounds)
    return [[s for s, m in zip(sources, member, strict=True) if m == area]
            for area in range(max(member) + 1)]


def road_lines(extraction: Extraction, rules: AttributeRules, attrs: dict) -> list[RoadLine]:
    """Extracted edges as lon/lat RoadLines with the attributes ``rules`` give them and the
    pipeline's confidence."""
    graph, frame = extraction.graph, extraction.frame
    facts = segment_attributes(graph, frame.resolution_m, rules)
    to_lonlat = Transformer.from_crs(frame.crs, "EPSG:4326", always_xy=True)
    lines = []
    for edge, fact in zip(graph.edges, facts, strict=True):
        xs, ys = frame.to_output @ (edge.coords[:, 0], edge.coords[:, 1])
        lon, lat = to_lonlat.transform(np.asarray(xs), np.asarray(ys))
        extra = {"through": fact.through}
        if fact.lanes_both_ways:
            extra[BOTH_WAYS_TAG] = fact.lanes_both_ways
        attributes = RoadAttributes(
            lanes_forward=fact.lanes_forward, lanes_backward=fact.lanes_backward,
            speed_limit_kph=fact.speed_limit_kph, road_class=fact.road_class,
            is_junction=fact.is_junction,
            width_m=round(edge.width_m, 2) if edge.width_m > 0 else None,
            attrs={**attrs, **extra}, confidence=round(min(max(edge.confidence, 0.0), 1.0), 3))
        lines.append(RoadLine(list(zip(lon.tolist(), lat.tolist(), strict=True)), attributes))
    return lines


@dataclass(frozen=True)
class LayerExtraction:
    """What ``ingest roads`` did: what it stored, from how many areas, with which classifier
    (one per area), sample and rules."""

    layer: str
    classifiers: list[str]
    """The classifier each connected area of the layer was extracted with."""
    summary: ImportSummary
    sample: str
    """"none" (zero-shot), or what the sample held, joined by " + ": "given", "drive
    trajectory" (an ipm-mosaic's stored drives), "layer labels", "review labels"."""
    rules: AttributeRules
    stored: list[RoadAttributes]
    """The attributes of the lines written (one per extracted edge)."""
    taught: Taught
    """The layer's labels and review labels the sample held."""
    change_set: dict[str, Any] | None = None
    """With ``--update``: the change set proposed (id, counts) instead of a written network."""
    sample_notes: list[str] = dataclasses.field(default_factory=list)
    """Per area the road model adapted in: whether the sample was used, and why
    (:meth:`ingest.roads.model.adapt.Adapted.summary`)."""

    def lines(self) -> list[str]:
        """The CLI's report: what was written, from what, and the attributes it got."""
        s = self.summary
        classes = Counter(a.road_class for a in self.stored).most_common()
        confidence = [a.confidence for a in self.stored if a.confidence is not None]
        junctions = sum(a.is_junction for a in self.stored)
        areas = (f" in {len(self.classifiers)} separate areas"
                 if len(self.classifiers) > 1 else "")
        used = [described] if (described := self.taught.describe()) else []
        notes = list(dict.fromkeys(self.sample_notes))
        if self.change_set is not None:
            c = self.change_set
            return [f"change set {c['id']} for network {c['network']} from layer {self.layer} "
                    f"({len(self.stored)} lines extracted): " + ", ".join(
                        f"{n} {kind}" for kind, n in c["counts"].items()), *notes,
                    f"review it: ugvmap network changes {c['network']} {c['id']}"]
        return [
            f"network {s.network}: {s.segments} segments, {s.nodes} nodes, "
            f"{s.total_length_m / 1000:.3f} km extracted from layer {self.layer}{areas} "
            f"({'/'.join(dict.fromkeys(self.classifiers))} classifier, sample: {self.sample})",
            "classes: " + ", ".join(f"{n} {c}" for c, n in classes)
            + f"; {junctions} junction segments; confidence mean "
              f"{np.mean(confidence):.2f}, min {min(confidence):.2f}",
            *used, *notes]


def _layer_sources(session: Session, slug: str) -> tuple[str, list[LayerSource]]:
    """(kind, sources with the one drawn on top first: what ``merge`` keeps where they
    overlap)."""
    layer = get_layer(session.connection(), slug)
    if layer is None:
        raise RoadsInputError(f"no raster layer {slug!r} (see `ugvmap layers list`)")
    if not layer["sources"]:
        raise RoadsInputError(f"layer {slug!r} has no sources")
    store = open_store()
    return layer["kind"], [LayerSource(s["name"], store.resolve(s["uri"]))
                           for s in reversed(layer["sources"])]


def _no_road(slug: str, classifier: str, sample: str) -> str:
    if sample == "none":
        advice = "give a training sample (--train-box / --train-lines) to adapt it"
    elif sample.startswith("drive trajectory"):
        advice = ("the drive's imagery may not show a road surface; give a training sample "
                  "(--train-box / --train-lines)")
    else:
        advice = f"check the training sample (and the layer's: `ugvmap layers labels {slug}`)"
    return f"no road found in layer {slug!r} with the {classifier} classifier; {advice}"


ADAPTING: tuple[Classifier, ...] = ("auto", "model", "adapted")
"""The classifiers that are the road model: it adapts to not-road labels alone (a reviewer's
deleted false roads), where a per-job classifier has no road to learn from."""


def _area_labels(image: Image, sample: GeoSample, area: Sequence[LayerSource], areas: int,
                 classifier: Classifier, required: bool) -> np.ndarray | None:
    """The sample's labels on one area's mosaic, or None where it labels nothing the
    classifier can use there and the road model may run zero-shot instead (``auto``). The
    road model takes not-road labels alone; a per-job classifier needs road. Refused when a
    ``required`` sample (the user's, a drive) labels no road in a layer of one area, or in an
    area a per-job classifier would have nothing to learn from."""
    assert image.crs is not None  # a layer's sources are all EPSG:3857
    labels = burn_sample(image.pixels.shape[:2], image.transform, image.crs, sample,
                         image.valid)
    if (labels == ROAD).any() or (classifier in ADAPTING and labels.any()):
        return labels
    if required and areas == 1:
        raise RoadsInputError(NO_SAMPLE_ROAD)
    if classifier not in ("auto", "model"):
        raise RoadsInputError(
            f"the training sample covers no road in the area of "
            f"{', '.join(s.name for s in area)}, one of the layer's {areas} separate areas: "
            f"give a sample there too, or use --classifier auto (the road model, zero-shot "
            f"where there is no sample)" if areas > 1 else
            f"the {classifier} classifier needs road in its sample: the layer's labels "
            f"label no road on its imagery; give --train-box / --train-lines, or use "
            f"--classifier auto")
    return None


def ingest_layer_roads(session: Session, slug: str, network: str, sample: GeoSample | None,
                       params: ExtractParams, *, rules: AttributeRules | None = None,
                       replace: bool = False, progress: bool = False, labels: bool = True,
                       review_labels: bool = True, update: bool = False,
                       tolerances: dict[str, float] | None = None) -> LayerExtraction:
    """Extract layer ``slug``'s roads into network ``network`` in the caller's transaction,
    each connected area of its sources as one mosaic (:func:`source_areas`).

    ``sample`` None: an ipm-mosaic's stored drives are the sample, else the road model runs
    zero-shot. The layer's stored labels (``labels``) and the review of the networks
    extracted from it (``review_labels``) are added to it (:mod:`ingest.roads.taught`),
    read before anything is written (``replace`` clears the network's edit history).
    ``rules`` override the network's attribute rules for this job. ``update``: the network
    is not written but matched with the extraction, whose changes are proposed as a change
    set (:mod:`ingest.network.update`, with ``tolerances`` overriding the matching's); the
    layer row stays share-locked from the start, so
    a re-ingest of the layer waits for the update instead of changing its imagery under it.
    """
    layer_area = coverage_of_layer(session, slug) if update else None
    kind, sources = _layer_sources(session, slug)
    team = taught(session, slug, labels=labels, review=review_labels)
    used = ["given"] if sample is not None else []
    if kind == "ipm-mosaic" and params.classifier == "auto":
        params = dataclasses.replace(params, classifier=IPM_CLASSIFIER)
    if kind == "ipm-mosaic" and sample is None:
        drives = layer_trajectories(session, slug)
        if drives:
            sample = GeoSample(road_lines=drives, line_width_m=TRAJECTORY_WIDTH_M,
                               not_road_beyond_m=3 * TRAJECTORY_WIDTH_M, open_ends=True)
            used = ["drive trajectory"]
        elif team.sample.empty:
            raise RoadsInputError(
                f"layer {slug!r} is an ipm-mosaic without a stored drive (made by `ugvmap "
                "ingest raster`, or before drives were kept): give a training sample "
                "(--train-lines / --train-box, or the layer's labels), or ingest the drive "
                "with `ugvmap ingest ipm`")
    required = sample is not None
    sample = merged(sample, team.sample)
    used += [f"{what} labels" for what, part in (("layer", team.labels),
                                                  ("review", team.review))
             if part is not None and part.count]
    applied = effective_rules(session, network, rules)
    areas = source_areas(sources)
    lines: list[RoadLine] = []
    classifiers: list[str] = []
    notes: list[str] = []
    labelled = False
    for area in areas:
        image = layer_mosaic([s.path for s in area], [s.name for s in area])
        burnt = (None if sample is None else
                 _area_labels(image, sample, area, len(areas), params.classifier, required))
        labelled = labelled or burnt is not None
        extraction = extract_roads(image, burnt, params, progress=progress)
        classifiers.append(extraction.classifier)
        notes += [extraction.sample_note] if extraction.sample_note else []
        lines += road_lines(extraction, applied, {"extracted_from": slug,
                                                  "classifier": extraction.classifier})
    if required and not labelled:
        raise RoadsInputError(NO_SAMPLE_ROAD)
    if not lines:
        raise RoadsInputError(_no_road(slug, "/".join(dict.fromkeys(classifiers)),
                                       " + ".join(used) or "none"))
    if layer_area is not None:
        area, layer_id, version = layer_area
        proposed = update_from_lines(session, network, lines, f"layer:{slug}", area,
                                     (layer_id, version), tol=Tolerances(**(tolerances or {})))
        summary = ImportSummary(network, 0, 0, 0, 0.0, len(lines))
        return LayerExtraction(slug, classifiers, summary, " + ".join(used) or "none",
                               applied, [line.attributes for line in lines], team, proposed,
                               notes)
    summary = write_network(session, network, lines, replace=replace, node_crossings=False)
    return LayerExtraction(slug, classifiers, summary, " + ".join(used) or "none", applied,
                           [line.attributes for line in lines], team, sample_notes=notes)


def window_roads(session: Session, slug: str, bbox: LonLatBox, sample: GeoSample | None,
                 params: ExtractParams) -> tuple[list[RoadLine], Extraction]:
    """(roads, the extraction: its classifier and what it made of the sample) of one lon/lat
    window of layer ``slug``: a preview of the view on
    the map. Only the sources meeting the window are read, and only that window of them
    (:func:`layer_mosaic` with bounds), so its cost follows the window, not the layer. The
    sample's labels there make the model adapt (zero-shot where they label nothing there).
    The lines get the default attribute rules: they go to no network yet."""
    _, sources = _layer_sources(session, slug)
    to_map = Transformer.from_crs("EPSG:4326", "EPSG:3857", always_xy=True)
    (left, right), (bottom, top) = to_map.transform([bbox[0], bbox[2]], [bbox[1], bbox[3]])
    window = box(left, bottom, right, top)
    meeting = []
    for source in sources:
        with rasterio.open(source.path) as dataset:
            if box(*dataset.bounds).intersects(window):
                meeting.append(source)
    if not meeting:
        raise RoadsInputError(f"the window {bbox} does not meet layer {slug!r}'s imagery")
    image = layer_mosaic([s.path for s in meeting], [s.name for s in meeting],
                         (left, bottom, right, top))
    labels = None
    if sample is not None:
        assert image.crs is not None
        burnt = burn_sample(image.pixels.shape[:2], image.transform, image.crs, sample,
                            image.valid)
        labels = burnt if burnt.any() else None
    extraction = extract_roads(image, labels, params)
    attrs = {"extracted_from": slug, "classifier": extraction.classifier}
    return road_lines(extraction, AttributeRules(), attrs), extraction
