"""Buffer evaluation of extracted road centerlines (Heipke/Wiedemann completeness/correctness).

Both centerlines are rasterised on one grid; for each buffer radius r:

* precision (correctness): share of predicted centerline pixels within r of the ground truth,
* recall (completeness): share of ground-truth centerline pixels within r of the prediction,
* quality: matched prediction / (prediction + unmatched ground truth).

Inputs are GeoJSON centerlines (pixel or map coordinates) or mask images (thinned to their
centerline first, so a road-width label and a one-pixel centerline score the same).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from pyproj import CRS, Transformer
from rasterio.transform import Affine

from ingest.roads import RoadsInputError
from ingest.roads.curve import arc_length
from ingest.roads.georef import pixel_size_m, read_band
from ingest.roads.skeleton import thin


@dataclass(frozen=True)
class BufferScore:
    """Precision, recall and quality at one buffer radius."""
    radius_px: float
    radius_m: float | None
    precision: float
    recall: float
    quality: float


def buffer_scores(pred: np.ndarray, gt: np.ndarray, radii_px: Sequence[float],
                  resolution_m: float | None = None,
                  region: np.ndarray | None = None) -> list[BufferScore]:
    """Precision/recall/quality of centerline rasters ``pred`` vs ``gt`` at each radius.

    ``region`` restricts which centerline pixels are counted (e.g. the quadrants not used for
    training); distances are still measured over the whole grid.
    """
    if pred.shape != gt.shape:
        raise RoadsInputError(f"prediction grid {pred.shape} differs from ground truth {gt.shape}")
    pred, gt = pred.astype(bool), gt.astype(bool)
    to_gt = _distance_to(gt)
    to_pred = _distance_to(pred)
    p = pred if region is None else pred & region
    g = gt if region is None else gt & region
    dp, dg = to_gt[p], to_pred[g]
    n_p, n_g = len(dp), len(dg)
    scores = []
    for r in radii_px:
        tp_p = int((dp <= r).sum())
        tp_g = int((dg <= r).sum())
        denom = n_p + n_g - tp_g
        scores.append(BufferScore(
            radius_px=float(r),
            radius_m=None if resolution_m is None else round(r * resolution_m, 3),
            precision=tp_p / n_p if n_p else 0.0,
            recall=tp_g / n_g if n_g else 0.0,
            quality=tp_p / denom if denom else 0.0))
    return scores


def _distance_to(mask: np.ndarray) -> np.ndarray:
    """Euclidean distance (pixels) of every pixel to the nearest set pixel of ``mask``."""
    if not mask.any():
        return np.full(mask.shape, np.inf, np.float32)
    return cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def rasterize_lines(lines: Sequence[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """8-connected one-pixel raster of polylines given in pixel-corner coordinates."""
    canvas = np.zeros(shape, np.uint8)
    pts = [np.round((np.asarray(line, float) - 0.5) * 16).astype(np.int32)
           for line in lines if len(line) >= 2]
    if pts:
        cv2.polylines(canvas, pts, False, 1, thickness=1, lineType=cv2.LINE_8, shift=4)
    return canvas.astype(bool)


def line_pixels(path: Path, to_pixel: Affine) -> list[np.ndarray]:
    """A GeoJSON file's (multi)linestrings in an image's pixel-corner coordinates
    (``to_pixel``: the image's inverse transform; the file must be in the image's CRS)."""
    lines, _, _ = _read_geojson(path)
    return [np.column_stack(to_pixel @ (line[:, 0], line[:, 1])) for line in lines]


def distance_to_lines_m(lines: Sequence[np.ndarray], shape: tuple[int, int],
                        resolution_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(one-pixel centerline raster, every pixel's distance to it in metres)."""
    centre = rasterize_lines(lines, shape)
    return centre, _distance_to(centre) * resolution_m


# --- loading PRED / GT files ---------------------------------------------------------------

@dataclass(frozen=True)
class Grid:
    """The raster both centerlines are drawn on."""

    shape: tuple[int, int]
    to_pixel: Affine
    """Coordinates in ``crs`` -> pixel-corner coordinates."""
    crs: CRS | None
    resolution_m: float | None


def _is_geojson(path: Path) -> bool:
    return path.suffix.lower() in (".geojson", ".json")


def _read_geojson(path: Path) -> tuple[list[np.ndarray], CRS | None, float | None]:
    """Line coordinates, their CRS (None = pixel space) and declared metres per unit."""
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RoadsInputError(f"{path}: not a readable GeoJSON file ({exc})") from exc
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        raise RoadsInputError(f"{path}: expected a GeoJSON FeatureCollection")
    lines = []
    for feature in doc.get("features", []):
        geom = (feature or {}).get("geometry") or {}
        if geom.get("type") == "LineString":
            lines.append(np.asarray(geom["coordinates"], float)[:, :2])
        elif geom.get("type") == "MultiLineString":
            lines += [np.asarray(part, float)[:, :2] for part in geom["coordinates"]]
    if ("crs" in doc and doc["crs"] is None) or doc.get("coordinate_space") == "pixel":
        return lines, None, doc.get("resolution_m")
    name = ((doc.get("crs") or {}).get("properties") or {}).get("name", "OGC:CRS84")
    return lines, CRS.from_user_input(name), None


def _local_metric_crs(lines: Sequence[np.ndarray], crs: CRS) -> CRS:
    """An azimuthal equidistant CRS centred on the lines: metres, negligible distortion."""
    to_ll = Transformer.from_crs(crs, "OGC:CRS84", always_xy=True)
    pts = np.vstack(lines)
    lon, lat = to_ll.transform(pts[:, 0].mean(), pts[:, 1].mean())
    return CRS.from_proj4(f"+proj=aeqd +lat_0={lat} +lon_0={lon} +datum=WGS84 +units=m")


def _project(lines: Sequence[np.ndarray], src: CRS | None, dst: CRS | None
             ) -> list[np.ndarray]:
    if src is None or dst is None or src == dst:
        if (src is None) != (dst is None):
            raise RoadsInputError("cannot compare pixel coordinates with map coordinates")
        return list(lines)
    t = Transformer.from_crs(src, dst, always_xy=True)
    return [np.column_stack(t.transform(line[:, 0], line[:, 1])) for line in lines]


def _grid_for_lines(sets: Sequence[tuple[list[np.ndarray], CRS | None, float | None]],
                    resolution_m: float | None) -> tuple[Grid, list[list[np.ndarray]]]:
    """A grid covering two GeoJSON line sets (pixel space, or a local metric CRS)."""
    crs = sets[0][1] or sets[1][1]
    if crs is None:
        declared = resolution_m or sets[0][2] or sets[1][2]
        lines = [_project(s[0], s[1], None) for s in sets]
        pts = np.vstack([p for group in lines for p in group] or [np.zeros((1, 2))])
        shape = (math.ceil(pts[:, 1].max()) + 2, math.ceil(pts[:, 0].max()) + 2)
        return Grid(shape, Affine.identity(), None, declared), lines
    metric = _local_metric_crs([p for s in sets for p in s[0]], crs)
    lines = [_project(s[0], s[1], metric) for s in sets]
    res = resolution_m or 0.5
    pts = np.vstack([p for group in lines for p in group])
    x0, y1 = pts[:, 0].min() - 10 * res, pts[:, 1].max() + 10 * res
    shape = (math.ceil((y1 - pts[:, 1].min()) / res) + 10, math.ceil((pts[:, 0].max() - x0) / res)
             + 10)
    to_pixel = ~(Affine.translation(x0, y1) @ Affine.scale(res, -res))
    return Grid(shape, to_pixel, metric, res), lines


def load_centerlines(pred_path: Path, gt_path: Path, resolution_m: float | None = None
                     ) -> tuple[np.ndarray, np.ndarray, float | None]:
    """Prediction and ground-truth centerline rasters on one grid, and metres per pixel."""
    paths = (Path(pred_path), Path(gt_path))
    for p in paths:
        if not p.is_file():
            raise RoadsInputError(f"{p}: no such file")
    vectors = {p: _read_geojson(p) for p in paths if _is_geojson(p)}
    masks = {p: read_band(p) for p in paths if not _is_geojson(p)}
    if not masks:
        grid, lines = _grid_for_lines([vectors[p] for p in paths], resolution_m)
        rasters = [rasterize_lines([_apply(grid.to_pixel, ln) for ln in group], grid.shape)
                   for group in lines]
        return rasters[0], rasters[1], grid.resolution_m
    first = next(iter(masks.values()))
    shape, transform, crs = first[0].shape, first[1], first[2]
    if any(m[0].shape != shape for m in masks.values()):
        raise RoadsInputError("the two mask images differ in size")
    res = resolution_m or (pixel_size_m(transform, crs, shape) if transform and crs else None)
    to_pixel = ~transform if transform else Affine.identity()
    out = []
    for p in paths:
        if p in masks:
            out.append(thin(masks[p][0] >= 128))
        else:
            centerlines, src_crs, declared = vectors[p]
            res = res or declared
            out.append(rasterize_lines([_apply(to_pixel, ln)
                                        for ln in _project(centerlines, src_crs, crs)], shape))
    return out[0], out[1], res


def _apply(t: Affine, line: np.ndarray) -> np.ndarray:
    xs, ys = t @ (line[:, 0], line[:, 1])
    return np.column_stack([xs, ys])


def scores_json(scores: Sequence[BufferScore]) -> str:
    """The scores as JSON, for scripts (``evaluate-roads --json``)."""
    return json.dumps([asdict(s) for s in scores], indent=2)
def turn_share(lines: list[np.ndarray], step: float, degrees: float) -> tuple[float, int]:
    """Share of ``step``-long steps along ``lines`` (resampled) that turn by more than
    ``degrees`` from the previous step, and how many turns were counted: how staircase-like
    a set of centrelines is (a road bends that fast only inside a junction)."""
    turns = []
    for line in lines:
        cum = arc_length(line)
        if cum[-1] < 2 * step:
            continue
        s = np.arange(0.0, cum[-1] + 1e-9, step)
        pts = np.column_stack([np.interp(s, cum, line[:, 0]), np.interp(s, cum, line[:, 1])])
        d = np.diff(pts, axis=0)
        heading = np.arctan2(d[:, 1], d[:, 0])
        turn = np.abs((np.diff(heading) + math.pi) % (2 * math.pi) - math.pi)
        turns.append(np.degrees(turn))
    if not turns:
        return 0.0, 0
    all_turns = np.concatenate(turns)
    return float((all_turns > degrees).mean()), len(all_turns)
