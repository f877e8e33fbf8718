"""Accumulate placed patches zone by zone, with bounded memory, and write finished zones.

Each open zone keeps only the 256 x 256 px chunks that received pixels, so memory follows the
area the vehicle saw (a 30 m wide corridor), not the zone size. A zone is finished when the
vehicle is farther from it than ``reach_px``: it is written at once as a zone mosaic (tiled,
sparse GeoTIFF + ``.zone.json`` sidecar, the format ``ugvmap ingest raster`` reads) and its
memory freed, so a long drive holds only the few zones around the vehicle. If the drive comes
back to a finished zone, a new pass of that zone is started and written as its own file; the
tile server draws later sources over earlier ones.

Blend modes (how pixels from several frames combine; measured in ``bench/ipm.py``):

* ``nearest`` (default): each ground pixel keeps the sample taken nearest to the camera. The
  panorama's ground resolution falls with the square of the distance, so this keeps the
  sharpest view of every pixel and never mixes two views (no ghosting).
* ``later``: each frame paints over earlier ones. For a vehicle driving forward, the last
  frame that sees a pixel sees it at the rear edge of the window: the farthest, blurriest view.
* ``weighted``: average of all views weighted by 1 / (d² + 1 m²) (nearer dominates).
"""

from __future__ import annotations

import contextlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import rasterio
from rasterio.enums import ColorInterp
from rasterio.windows import Window

from ingest.ipm.grid import ZoneGrid
from ingest.ipm.place import PlacedPatch

CHUNK_PX = 256
BLENDS = ("nearest", "later", "weighted")
#: A zone whose coverage, shrunk by one pixel, has fewer pixels than this is a sliver at the
#: very edge of the window; it is dropped (the raster ingest refuses a source that warps to
#: nothing, and such a sliver is at most a hair line of the neighbouring zone).
MIN_CORE_PX = 64


class Chunk:
    """One 256 x 256 px block of a zone: colour + what the blend mode needs."""

    def __init__(self, blend: str) -> None:
        shape = (CHUNK_PX, CHUNK_PX)
        self.blend = blend
        if blend == "weighted":
            self.sum = np.zeros((*shape, 3), np.float32)
            self.weight = np.zeros(shape, np.float32)
        else:
            self.colour = np.zeros((*shape, 3), np.uint8)
            # nearest: best squared distance so far (inf = empty); later: 0 / 1 coverage.
            self.score = np.full(shape, np.inf if blend == "nearest" else 0, np.float32)

    @property
    def nbytes(self) -> int:
        """Memory held by the chunk's buffers, for the stitcher's peak-memory figure."""
        return sum(a.nbytes for a in vars(self).values() if isinstance(a, np.ndarray))

    def add(self, rows: slice, cols: slice, colour: np.ndarray, valid: np.ndarray,
            dist2: np.ndarray, metre_px2: float) -> None:
        """Blend one patch's pixels into ``[rows, cols]`` of the chunk by the blend mode;
        ``metre_px2`` (1 m² in grid pixels²) keeps the weighted mode finite under the camera."""
        if self.blend == "nearest":
            better = valid & (dist2 < self.score[rows, cols])
            np.copyto(self.colour[rows, cols], colour, where=better[..., None])
            np.copyto(self.score[rows, cols], dist2, where=better)
        elif self.blend == "later":
            np.copyto(self.colour[rows, cols], colour, where=valid[..., None])
            self.score[rows, cols][valid] = 1
        else:
            w = np.where(valid, 1.0 / (dist2 + metre_px2), 0).astype(np.float32)
            self.sum[rows, cols] += colour * w[..., None]
            self.weight[rows, cols] += w

    def image(self) -> tuple[np.ndarray, np.ndarray]:
        """(colour uint8 (256, 256, 3), covered bool (256, 256))."""
        if self.blend == "weighted":
            covered = self.weight > 0
            colour = self.sum / np.maximum(self.weight, 1e-30)[..., None]
            return np.clip(colour + 0.5, 0, 255).astype(np.uint8), covered
        covered = np.isfinite(self.score) if self.blend == "nearest" else self.score > 0
        return self.colour, covered


@dataclass
class OpenZone:
    """A zone being stitched: only its touched chunks exist; ``pass_no`` > 1 when the drive
    came back to a zone already written (each pass is its own file)."""

    row: int
    col: int
    pass_no: int
    chunks: dict[tuple[int, int], Chunk] = field(default_factory=dict)


@dataclass
class StitchStats:
    """Counters for the job's summary and the benchmark, kept as zones are written."""

    zones_written: int = 0
    zones_dropped: int = 0
    covered_px: int = 0
    """Covered pixels counted in each zone's own part (not the overlap it shares with the
    next zone), so a pixel counts once per pass over it."""
    peak_bytes: int = 0
    peak_open_zones: int = 0


class ZoneStitcher:
    """``add`` placed patches in drive order; finished zones land in ``out_dir``."""

    def __init__(self, grid: ZoneGrid, blend: str, out_dir: Path, reach_px: float) -> None:
        if blend not in BLENDS:
            raise ValueError(f"blend must be one of {BLENDS}")
        self.grid, self.blend, self.out_dir, self.reach_px = grid, blend, out_dir, reach_px
        self.open: dict[tuple[int, int], OpenZone] = {}
        self.passes: dict[tuple[int, int], int] = {}
        self.written: list[Path] = []
        self.stats = StitchStats()
        self._bytes = 0
        self._metre_px2 = (1.0 / grid.resolution_m) ** 2

    def add(self, patch: PlacedPatch) -> None:
        """Blend ``patch`` into every zone it touches (overlapping zones each get their copy),
        opening zones and chunks as needed."""
        h, w = patch.shape
        box = (patch.col0, patch.row0, patch.col0 + w, patch.row0 + h)
        for key in self.grid.zones_meeting(*box):
            self._add_to_zone(key, patch, box)
        self.stats.peak_open_zones = max(self.stats.peak_open_zones, len(self.open))

    def _zone(self, key: tuple[int, int]) -> OpenZone:
        """The open zone ``key``, opened (as a new pass if it was written before) if need be."""
        zone = self.open.get(key)
        if zone is None:
            self.passes[key] = self.passes.get(key, 0) + 1
            zone = self.open[key] = OpenZone(*key, self.passes[key])
        return zone

    def _add_to_zone(self, key: tuple[int, int], patch: PlacedPatch,
                     box: tuple[int, int, int, int]) -> None:
        zc0, zr0, zc1, zr1 = self.grid.zone_box(*key)
        c0, r0 = max(box[0], zc0) - zc0, max(box[1], zr0) - zr0
        c1, r1 = min(box[2], zc1) - zc0, min(box[3], zr1) - zr0
        for ci in range(c0 // CHUNK_PX, (c1 - 1) // CHUNK_PX + 1):
            for ri in range(r0 // CHUNK_PX, (r1 - 1) // CHUNK_PX + 1):
                # Chunk-local and patch-local windows of the intersection.
                lc0, lc1 = max(c0, ci * CHUNK_PX), min(c1, (ci + 1) * CHUNK_PX)
                lr0, lr1 = max(r0, ri * CHUNK_PX), min(r1, (ri + 1) * CHUNK_PX)
                pc = slice(lc0 + zc0 - patch.col0, lc1 + zc0 - patch.col0)
                pr = slice(lr0 + zr0 - patch.row0, lr1 + zr0 - patch.row0)
                valid = patch.valid[pr, pc]
                if not valid.any():
                    continue
                chunks = self._zone(key).chunks
                chunk = chunks.get((ri, ci))
                if chunk is None:
                    chunk = chunks[(ri, ci)] = Chunk(self.blend)
                    self._bytes += chunk.nbytes
                    self.stats.peak_bytes = max(self.stats.peak_bytes, self._bytes)
                chunk.add(slice(lr0 - ri * CHUNK_PX, lr1 - ri * CHUNK_PX),
                          slice(lc0 - ci * CHUNK_PX, lc1 - ci * CHUNK_PX),
                          patch.colour[pr, pc], valid, patch.dist2[pr, pc], self._metre_px2)

    def close_far(self, col: float, row: float) -> None:
        """Write every open zone farther than ``reach_px`` from global pixel (col, row)."""
        for key in list(self.open):
            c0, r0, c1, r1 = self.grid.zone_box(*key)
            dx = max(c0 - col, 0, col - c1)
            dy = max(r0 - row, 0, row - r1)
            if dx * dx + dy * dy > self.reach_px ** 2:
                self._finish(self.open.pop(key))

    def close_all(self) -> None:
        """Write every zone still open: the end of the drive."""
        for key in list(self.open):
            self._finish(self.open.pop(key))

    def _finish(self, zone: OpenZone) -> None:
        try:
            path = self._write(zone)
        finally:
            self._bytes -= sum(c.nbytes for c in zone.chunks.values())
        if path is None:
            self.stats.zones_dropped += 1
        else:
            self.written.append(path)
            self.stats.zones_written += 1

    def _write(self, zone: OpenZone) -> Path | None:
        """Write one zone as a sparse tiled GeoTIFF + sidecar; None if it is only a sliver."""
        images = {key: chunk.image() for key, chunk in zone.chunks.items()}
        core = sum(int(cv2.erode(cov.astype(np.uint8), np.ones((3, 3), np.uint8)).sum())
                   for _, cov in images.values())
        if core < MIN_CORE_PX:
            return None
        sidecar = self.grid.sidecar(zone.row, zone.col)
        width, height = self.grid.zone_size_px
        own_w, own_h = self.grid.step_px
        suffix = "" if zone.pass_no == 1 else f"_pass{zone.pass_no}"
        path = self.out_dir / f"zone_r{zone.row}_c{zone.col}{suffix}.tif"
        profile = {"driver": "GTiff", "width": width, "height": height, "count": 4,
                   "dtype": "uint8", "crs": sidecar.crs(), "transform": sidecar.transform(),
                   "tiled": True, "blockxsize": CHUNK_PX, "blockysize": CHUNK_PX,
                   "sparse_ok": True, "compress": "zstd", "zstd_level": 1,
                   "photometric": "RGB"}
        self.out_dir.mkdir(parents=True, exist_ok=True)
        try:
            with rasterio.open(path, "w", **profile) as ds:
                ds.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue,
                                  ColorInterp.alpha]
                for (ri, ci), (colour, covered) in sorted(images.items()):
                    c0, r0 = ci * CHUNK_PX, ri * CHUNK_PX
                    w, h = min(CHUNK_PX, width - c0), min(CHUNK_PX, height - r0)
                    alpha = np.where(covered[:h, :w], 255, 0).astype(np.uint8)
                    rgb = np.moveaxis(colour[:h, :w, ::-1], -1, 0)
                    ds.write(np.concatenate([rgb, alpha[None]]), window=Window(c0, r0, w, h))
                    self.stats.covered_px += int(
                        covered[:max(0, min(h, own_h - r0)), :max(0, min(w, own_w - c0))].sum())
            path.with_name(path.name + ".zone.json").write_text(json.dumps({
                "zone": {"row": zone.row, "col": zone.col},
                "origin": {"lat": self.grid.origin_lat, "lon": self.grid.origin_lon},
                "resolution_m": self.grid.resolution_m, "zone_size_px": [width, height],
                "overlap_px": list(self.grid.overlap_px), "frame": sidecar.frame}))
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
            raise
        return path
