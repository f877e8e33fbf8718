"""Run the shipped road model with onnxruntime: no torch, bounded memory, any image size.

The network sees the image through overlapping tiles whose origins sit on its 16 px grid
(so pooling windows line up with an untiled run), and the tile outputs are blended with a
weight that ramps down over the overlap, where a tile's own border padding spoils its view.
Away from the image border the result matches one whole-image run to within a few thousandths
of probability and the same road mask (``tests/test_roads_model.py``), while memory holds one
tile of activations.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from ingest.roads import RoadsInputError

if TYPE_CHECKING:
    import onnxruntime as ort

MODEL_DIR = Path(__file__).resolve().parents[3] / "models" / "roads-v2"
GRID_PX = 16
TILE_PX = 1024
OVERLAP_PX = 128


@dataclass(frozen=True)
class RoadModel:
    """An ONNX road model and what its metadata says about it."""

    path: Path
    resolution_m: float
    """Ground resolution the model was trained at."""
    threshold: float
    """Probability threshold chosen on the training hold-out."""
    session: ort.InferenceSession
    """The loaded network (onnxruntime is imported only when a model is opened)."""
    feature_outputs: tuple[str, ...] = ("features",)
    """What adaptation reads: the decoder ``features``, and the encoder ``context`` where
    the file has it (models exported before it, and roads-v1, lack it)."""
    decoder_channels: int = 16
    """How many of :func:`predict`'s feature channels are the decoder's (the context's
    follow)."""


def default_model_path() -> Path:
    """``UGVMAP_ROAD_MODEL`` or the model committed under ``models/roads-v2``."""
    return Path(os.environ.get("UGVMAP_ROAD_MODEL") or MODEL_DIR / "model.onnx")


@lru_cache(maxsize=4)
def load_model(path: Path | None = None, threads: int = 2) -> RoadModel:
    """Open the ONNX file once per process (sessions are thread-safe for ``run``)."""
    import onnxruntime as ort

    path = path or default_model_path()
    if not path.is_file():
        raise RoadsInputError(f"road model {path} not found: train one with `ugvmap roads "
                              "train` or set UGVMAP_ROAD_MODEL")
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    try:
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own untyped errors for bad files
        raise RoadsInputError(f"{path}: not a usable ONNX road model ({exc})") from exc
    meta = {k: json.loads(v) for k, v in session.get_modelmeta().custom_metadata_map.items()}
    if "resolution_m" not in meta:
        raise RoadsInputError(f"{path}: ONNX file lacks ugvmap's metadata (resolution_m)")
    outputs = {o.name: o.shape for o in session.get_outputs()}
    channels = outputs.get("features", [None, None])[1]
    return RoadModel(path=path, resolution_m=float(meta["resolution_m"]),
                     threshold=float(meta.get("threshold", 0.5)), session=session,
                     feature_outputs=tuple(n for n in ("features", "context") if n in outputs),
                     decoder_channels=channels if isinstance(channels, int) else 16)


def _ramp(n: int, overlap: int) -> np.ndarray:
    """1-D blend weight: rises over ``overlap`` px at both ends, 1 in between, never 0.

    The rise is cubic, not linear: a pixel a few pixels from a tile's edge has almost no
    context in that tile, and the pretrained encoder (stride 16) sees further than the
    overlap, so such predictions must weigh next to nothing against the neighbour's. Measured
    on a synthetic town, tiled against whole: mean change 0.0014 -> 0.0002 and decisions that
    differ 0.10 % -> 0.02 % (roads-v2's first model)."""
    w = np.ones(n, np.float32)
    if overlap:
        edge = ((np.arange(overlap, dtype=np.float32) + 0.5) / overlap) ** 3
        k = min(overlap, n // 2)
        w[:k] = edge[:k]
        w[n - k:] = np.minimum(w[n - k:], edge[:k][::-1])
    return w


def _axis_plan(n: int, tile: int, overlap: int) -> tuple[int, int, list[int]]:
    """(tile size, padded length, tile starts) along one axis of ``n`` pixels.

    The image is padded by ``overlap`` in front, so padded 0 is image -overlap; full tiles
    step by ``tile - 2 * overlap`` and each one's full-weight middle abuts the next one's.
    An axis that fits in one tile gets one tile rounded up to the 16 px grid.
    """
    if n + 2 * overlap <= tile:
        size = -(-(n + 2 * overlap) // GRID_PX) * GRID_PX
        return size, size, [0]
    step = tile - 2 * overlap
    count = -(-n // step)
    return tile, count * step + 2 * overlap, [i * step for i in range(count)]


def _dihedral(x: np.ndarray, k: int) -> np.ndarray:
    """The k-th (0..7) of the square's symmetries on the last two axes: k % 4 quarter turns,
    then a mirror for k >= 4."""
    x = np.rot90(x, k % 4, axes=(-2, -1))
    return x[..., ::-1] if k >= 4 else x


def _undo_dihedral(x: np.ndarray, k: int) -> np.ndarray:
    if k >= 4:
        x = x[..., ::-1]
    return np.rot90(x, -(k % 4), axes=(-2, -1))


def _run(model: RoadModel, x: np.ndarray, names: list[str], tta: int) -> list[np.ndarray]:
    """The network's outputs for one tile, averaged over ``tta`` symmetries of it."""
    outs = None
    for k in range(tta):
        got = model.session.run(names, {"rgb": np.ascontiguousarray(_dihedral(x, k))})
        back = [_undo_dihedral(o, k) for o in got]
        outs = back if outs is None else [a + b for a, b in zip(outs, back, strict=True)]
    assert outs is not None  # tta >= 1
    return outs if tta == 1 else [o / tta for o in outs]


def halve(a: np.ndarray) -> np.ndarray:
    """The mean of every 2 x 2 block of the last two axes (an odd last row or column is
    repeated): half the resolution, pixel (i, j) covering full pixels 2i..2i+1, 2j..2j+1."""
    rows, cols = a.shape[-2:]
    if rows % 2 or cols % 2:
        pad = [(0, 0)] * (a.ndim - 2) + [(0, rows % 2), (0, cols % 2)]
        a = np.pad(a, pad, mode="edge")
    a = a.astype(np.float32, copy=False)
    # Four strided views added: several times faster than a reshaped mean over two axes.
    out = a[..., 0::2, 0::2] + a[..., 1::2, 0::2]
    out += a[..., 0::2, 1::2]
    out += a[..., 1::2, 1::2]
    out *= 0.25
    return out


def quarter(a: np.ndarray) -> np.ndarray:
    """:func:`halve` twice: a quarter of the resolution, cell (i, j) covering pixels 4i..4i+3,
    4j..4j+3 (the encoder context's stride)."""
    return halve(halve(a))


def _cells(start: int, size: int, limit: int) -> tuple[slice, slice]:
    """(cells of the image, cells of the tile) where a tile's ``size`` cells starting at image
    cell ``start`` (negative in the padding) overlap the image's ``limit`` cells."""
    to = slice(max(start, 0), min(start + size, limit))
    return to, slice(to.start - start, to.stop - start)


def predict(model: RoadModel, rgb: np.ndarray, *, features: bool = False,
            context: bool = False,
            tile: int = TILE_PX, overlap: int = OVERLAP_PX, progress: bool = False,
            tta: int = 1) -> tuple[np.ndarray, np.ndarray | None]:
    """Road probability (rows, cols) float32 of normalised RGB on the model grid, and when
    asked for, what the adaptation reads: (C, ceil(rows / 4), ceil(cols / 4)), channels first
    as the network gives them, at a quarter of the resolution (:func:`quarter`): the decoder's
    features, then, with ``context``, the encoder's context where the model has it (its
    native stride). The one user, the adaptation, blurs them by 1.5 m anyway; at full
    resolution the decoder's 16 channels of a 3000 px image alone take 600 MB, the context's
    176 would take 6 GB.

    ``tile`` and ``overlap`` must be multiples of the 16 px grid; images smaller than a tile
    run as one (padded) tile. ``tta`` > 1 averages the network over that many rotations and
    mirror images of each tile (test-time augmentation: 1, 2, 4 or 8; costs as many runs).
    """
    if tta not in (1, 2, 4, 8):
        raise ValueError("tta must be 1, 2, 4 or 8")
    if tile % GRID_PX or overlap % GRID_PX or tile <= 2 * overlap:
        raise ValueError("tile and overlap must be multiples of 16 with tile > 2 x overlap")
    rows, cols = rgb.shape[:2]
    th, ph, row_starts = _axis_plan(rows, tile, overlap)
    tw, pw, col_starts = _axis_plan(cols, tile, overlap)
    padded = np.pad(rgb.astype(np.float32, copy=False),
                    ((overlap, ph - rows - overlap), (overlap, pw - cols - overlap), (0, 0)),
                    mode="reflect" if min(rows, cols) > 1 else "edge")
    acc = np.zeros((ph, pw), np.float32)
    weight = np.zeros((ph, pw), np.float32)
    # The features are gathered straight onto the image's quarter grid (no padding, C-ordered),
    # so the adaptation reads their 190-odd channels as one matrix without a copy of them.
    o4, q_rows, q_cols = overlap // 4, -(-rows // 4), -(-cols // 4)
    feat_acc: np.ndarray | None = None
    window = np.outer(_ramp(th, overlap), _ramp(tw, overlap))
    quarter_window = quarter(window)
    boxes = [(r, c) for r in row_starts for c in col_starts]
    names = ["road", *(model.feature_outputs if context else ("features",))] if features \
        else ["road"]
    for r, c in tqdm(boxes, desc="road model", unit="tile", disable=not progress, leave=False):
        x = np.ascontiguousarray(padded[r:r + th, c:c + tw].transpose(2, 0, 1))[None]
        out = _run(model, x, names, tta)
        acc[r:r + th, c:c + tw] += out[0][0, 0] * window
        weight[r:r + th, c:c + tw] += window
        if features:
            n = out[1].shape[1]
            if feat_acc is None:
                feat_acc = np.zeros((n + sum(o.shape[1] for o in out[2:]), q_rows, q_cols),
                                    np.float32)
            rows_to, rows_from = _cells(r // 4 - o4, th // 4, q_rows)
            cols_to, cols_from = _cells(c // 4 - o4, tw // 4, q_cols)
            w = quarter_window[rows_from, cols_from]
            # Weighed in place: a product's temporary of 190-odd channels took 3x the time.
            parts = [(slice(None, n), quarter(out[1][0]))]
            if len(out) > 2:
                parts.append((slice(n, None), out[2][0]))
            for to, got in parts:
                got = got[:, rows_from, cols_from]
                got *= w
                feat_acc[to, rows_to, cols_to] += got
    inner = (slice(overlap, overlap + rows), slice(overlap, overlap + cols))
    prob = acc[inner] / weight[inner]
    if feat_acc is not None:
        feat_acc /= quarter(weight)[o4:o4 + q_rows, o4:o4 + q_cols]
    return prob, feat_acc
