"""Centimetre centrelines on very fine mosaics: the graph's geometry refined on the source grid.

The road model sees the image on its own grid (1 m for ``roads-v1``), which is right for
finding roads but leaves a vehicle's own 0.03-0.1 m IPM mosaic's centreline a few
decimetres off: the probability's edges are only as sharp as the model's pixels, and a
sample made from the drive's trajectory (the vehicle's lane, not the road's centre) tilts
an adapted classifier towards one side. On such a mosaic the road's edges are sharp, so the
graph found on the working grid is refined where the pixels are:

1. the road's colour is learned from the mosaic itself, around the working-grid result:
   pixels near each centreline (within a quarter of its width) are road, pixels between
   0.75 and 1.5 widths away are not; the survey's spectral line
   (:func:`ingest.roads.classify.fit_spectral_line`) of the road pixels then scores pixels
   by their colour distance, a soft field that crosses 0.5 at ``k`` x the samples' mean
   distance (lane markings lie on the asphalt's grey line, so they count as road);
2. every edge is refined again by :func:`ingest.roads.geometry.refine_geometry` on that
   field, on the source grid: cross-sections, junctions where the approaches cross, the
   smoothing spline, simplification.

Only the band the cross-sections can reach is computed. A drive's mosaic is mostly verge and
no-data around a thin road (the 189-frame ring of ``bench/ipm_roads.py``: 27 MP, of which the
blocks within 1.5 road widths of the centreline hold 3 MP), and scoring every pixel's
colour, blurring it and spline-filtering it over the whole mosaic took 4 s of a 5 s
extraction. So the colour line is fitted on every ``SAMPLE_STRIDE``-th pixel (a colour line
needs thousands of samples, not millions), and the field and its spline coefficients are
computed in ``BLOCK_PX`` blocks that lie within ``BAND_WIDTHS`` road widths of a centreline,
each with ``MARGIN_PX`` of context so the blur and the spline prefilter are what the whole
mosaic would give; elsewhere the field is 0 (not road), and sections search no farther. A
section that reached the band's edge would find an edge there, some ``2 x BAND_WIDTHS``
widths from the other one, which the width rule of :mod:`ingest.roads.geometry` refuses.

Only the geometry and widths change; the topology and the confidence (the model's
probability) stay the working grid's.
"""

from __future__ import annotations

import math

import cv2
import networkx as nx
import numpy as np
from rasterio.transform import Affine
from scipy.ndimage import spline_filter

from ingest.roads.classify import (
    SpectralLine,
    bounded_by_background,
    fit_spectral_line,
    subsample_rows,
)
from ingest.roads.evaluate import rasterize_lines
from ingest.roads.geometry import edge_key, refine_geometry
from ingest.roads.georef import Image
from ingest.roads.graph import Edge, GraphParams, Node, RoadGraph
from ingest.roads.ridge import SOFT_MASK_SIGMA_PX, RoadField

MAX_SAMPLES = 200_000
"""Road pixels the colour line is fitted on (a random subset beyond that)."""
SAMPLE_STRIDE = 4
"""The colour samples are read from every this many pixels each way (16x fewer to sort by
their distance to the centrelines; at 0.05 m still ~1,000 road samples per metre of road)."""
BAND_WIDTHS = 1.5
"""The field is computed within this many road widths of a centreline (the widest edge's): a
road's edges are half a width from its centre, the working grid's centreline is within a
metre of it, and the colour line was trained on nothing farther."""
BLOCK_PX = 128
"""Side of the blocks the field is computed in."""
MARGIN_PX = 16
"""Context round a block: the blur reaches 4 px, and the cubic spline prefilter's influence
falls by 0.268 per pixel (below 1e-6 after 12)."""


def applies(source_m: float, working_m: float, fine_max_m: float) -> bool:
    """Refine on the source grid when it is at most ``fine_max_m`` per pixel and at least
    twice as fine as the working grid."""
    return 0 < source_m <= fine_max_m and working_m >= 2 * source_m


def _distance_to_lines(lines: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """Distance (source pixels) from every ``SAMPLE_STRIDE``-th pixel of a ``shape`` grid to
    ``lines`` (source pixel-corner coordinates)."""
    n = SAMPLE_STRIDE
    sub = (math.ceil(shape[0] / n), math.ceil(shape[1] / n))
    # Sample pixel (i, j) is source pixel (n i, n j), whose centre is n j + 0.5.
    centre = rasterize_lines([(line - 0.5) / n + 0.5 for line in lines], sub)
    return cv2.distanceTransform((~centre).astype(np.uint8), cv2.DIST_L2,
                                 cv2.DIST_MASK_PRECISE) * n


def _colour_line(pixels: np.ndarray, valid: np.ndarray | None, dist: np.ndarray,
                 width_px: float, k: float) -> SpectralLine | None:
    """The spectral line of the road pixels among every ``SAMPLE_STRIDE``-th one, ``dist``
    (:func:`_distance_to_lines`) from the centrelines, ended where the background samples lie
    on it (:func:`ingest.roads.classify.bounded_by_background`, ``k`` as there); None when
    they give no road or no background sample."""
    n = SAMPLE_STRIDE
    road = dist <= 0.25 * width_px
    background = (dist >= 0.75 * width_px) & (dist <= 1.5 * width_px)
    if valid is not None:
        road &= valid[::n, ::n]
        background &= valid[::n, ::n]
    if not road.any() or not background.any():
        return None
    samples = subsample_rows(pixels[::n, ::n][road], MAX_SAMPLES, 0).astype(np.float64)
    line = fit_spectral_line(samples)
    others = subsample_rows(pixels[::n, ::n][background], MAX_SAMPLES, 0).astype(np.float64)
    return bounded_by_background(line, samples, others, k * line.mean_distance)


def band_blocks(dist: np.ndarray, reach_px: float) -> list[tuple[int, int]]:
    """(row, col) indices of the ``BLOCK_PX`` blocks with a pixel within ``reach_px`` of the
    centrelines (``dist``: :func:`_distance_to_lines`)."""
    cells = BLOCK_PX // SAMPLE_STRIDE
    rows, cols = (math.ceil(d / cells) for d in dist.shape)
    padded = np.full((rows * cells, cols * cells), np.inf, np.float32)
    padded[:dist.shape[0], :dist.shape[1]] = dist
    nearest = padded.reshape(rows, cells, cols, cells).min(axis=(1, 3))
    # A sample pixel stands for the stride's square of pixels: up to stride - 1 nearer.
    near = nearest <= reach_px + SAMPLE_STRIDE
    return [(int(r), int(c)) for r, c in zip(*np.nonzero(near), strict=True)]


def colour_field(pixels: np.ndarray, valid: np.ndarray | None, line: SpectralLine,
                 limit: float, blocks: list[tuple[int, int]]) -> tuple[np.ndarray, np.ndarray]:
    """(soft road field, its cubic spline coefficients) of ``pixels``: 1 on the colour
    ``line``, 0.5 at ``limit``, blurred like a mask's edge; computed in ``blocks`` only
    (0 elsewhere), no-data counting as not road in the coefficients as in
    :meth:`ingest.roads.ridge.RoadField.coefficients`."""
    rows, cols = pixels.shape[:2]
    field = np.zeros((rows, cols), np.float32)
    coefficients = np.zeros((rows, cols), np.float64)
    for br, bc in blocks:
        r0, c0 = br * BLOCK_PX, bc * BLOCK_PX
        r1, c1 = min(r0 + BLOCK_PX, rows), min(c0 + BLOCK_PX, cols)
        wr0, wc0 = max(r0 - MARGIN_PX, 0), max(c0 - MARGIN_PX, 0)
        wr1, wc1 = min(r1 + MARGIN_PX, rows), min(c1 + MARGIN_PX, cols)
        raw = np.clip(1.0 - line.distance(pixels[wr0:wr1, wc0:wc1]) / (2 * limit), 0.0, 1.0)
        soft = cv2.GaussianBlur(raw, (0, 0), SOFT_MASK_SIGMA_PX)
        inner = (slice(r0 - wr0, r1 - wr0), slice(c0 - wc0, c1 - wc0))
        field[r0:r1, c0:c1] = soft[inner]
        on_data = soft.astype(np.float64)
        if valid is not None:
            on_data[~valid[wr0:wr1, wc0:wc1]] = 0.0
        coefficients[r0:r1, c0:c1] = spline_filter(on_data, order=3, mode="nearest")[inner]
    return field, coefficients


def refine_on_source(graph: RoadGraph, image: Image, to_source: Affine, params: GraphParams,
                     k: float) -> RoadGraph:
    """``graph`` (working-grid coordinates, ``to_source`` mapping them to source pixels) with
    every edge's geometry and width refined on the source grid (see module doc)."""
    if not graph.edges:
        return graph
    res = image.resolution_m
    to_work = ~to_source

    def source(xy: np.ndarray) -> np.ndarray:
        return np.column_stack(to_source @ (xy[:, 0], xy[:, 1]))

    lines = [source(e.coords) for e in graph.edges]
    widths = [e.width_m / res for e in graph.edges]
    dist = _distance_to_lines(lines, image.pixels.shape[:2])
    colour = _colour_line(image.pixels, image.valid, dist, float(np.median(widths)), k)
    if colour is None:
        return graph
    reach_px = BAND_WIDTHS * max(widths)
    blocks = band_blocks(dist, reach_px)
    field, coefficients = colour_field(image.pixels, image.valid, colour,
                                       k * colour.mean_distance, blocks)
    road = RoadField(field, 0.5, image.valid)
    g = nx.MultiGraph()
    for n in graph.nodes:
        g.add_node(n.id, xy=tuple(source(np.array([n.xy]))[0]))
    chains = {}
    keys = []
    for e, line in zip(graph.edges, lines, strict=True):
        key = g.add_edge(e.source, e.target, start=e.source)
        chains[edge_key(e.source, e.target, key)] = line[1:-1]
        keys.append(edge_key(e.source, e.target, key))
    # Beyond the band the field is 0: a section need not look farther.
    shapes, node_xy = refine_geometry(g, chains, road, coefficients, res, params.station_m,
                                      params.smooth_m, params.simplify_m, params.max_turn_deg,
                                      min(params.max_half_width_m, reach_px * res))
    nodes = []
    for n in graph.nodes:
        x, y = to_work @ node_xy[n.id]
        nodes.append(Node(n.id, (float(x), float(y)), n.degree))
    edges = []
    for e, key in zip(graph.edges, keys, strict=True):
        shape = shapes[key]
        coords = np.column_stack(to_work @ (shape.coords[:, 0], shape.coords[:, 1]))
        width_m = e.width_m if shape.width_px is None else round(shape.width_px * res, 2)
        length_m = float(np.linalg.norm(np.diff(shape.coords, axis=0), axis=1).sum()) * res
        edges.append(Edge(e.id, e.source, e.target, coords, round(length_m, 2), width_m,
                          max(1, round(width_m / params.lane_width_m)), e.confidence))
    return RoadGraph(nodes, edges)
