"""Relief images from a height grid: slope, hillshade and Terrarium encoding (pure functions).

Slope and hillshade use Horn's 3x3 gradient, the method ``gdaldem`` uses by default, so our
slope tiles can be checked against ``gdaldem slope``. They are written here rather than run
through GDAL because a web-mercator tile's pixels change ground size with latitude (GDAL's
DEM tools take one scale per raster), and the tile path must not write a dataset per request.

Inputs are padded by one pixel on every side (the tile's neighbours), so the edges of a tile
have a gradient and adjacent tiles join without seams; NaN marks nodata, and a pixel whose
3x3 window meets nodata has no slope (NaN), as ``gdaldem`` leaves such edges undefined.
"""

from __future__ import annotations

import numpy as np

#: Terrarium's offset: height = R * 256 + G + B / 256 - 32768 (Mapzen/AWS terrain tiles).
TERRARIUM_OFFSET = 32768.0
#: The slope ramp: (degrees, BGR colour) stops, linear between them. Green where a vehicle
#: drives easily, yellow-orange on what a UGV climbs with care, red and dark red beyond.
SLOPE_STOPS: tuple[tuple[float, tuple[int, int, int]], ...] = (
    (0.0, (96, 200, 26)),      # #1ac860
    (10.0, (59, 217, 166)),    # #a6d93b
    (20.0, (40, 200, 250)),    # #fac828
    (30.0, (30, 120, 240)),    # #f0781e
    (45.0, (40, 30, 200)),     # #c81e28
    (60.0, (30, 10, 90)),      # #5a0a1e
)


def horn_gradient(padded: np.ndarray, res: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """dz/dx (east) and dz/dy (north) by Horn's formula on the interior of ``padded``.

    ``res`` is the ground size of a (square) pixel, per output row (web mercator, whose
    pixels shrink with latitude) or one number. Rows run north to south, as in a raster.
    """
    z = padded.astype(np.float64)
    a, b, c = z[:-2, :-2], z[:-2, 1:-1], z[:-2, 2:]
    d, f = z[1:-1, :-2], z[1:-1, 2:]
    g, h, i = z[2:, :-2], z[2:, 1:-1], z[2:, 2:]
    size = np.asarray(res, np.float64).reshape(-1, 1) if np.ndim(res) else float(res)
    dzdx = ((c + 2 * f + i) - (a + 2 * d + g)) / (8 * size)
    dzdy = ((a + 2 * b + c) - (g + 2 * h + i)) / (8 * size)
    hole = np.isnan(z[1:-1, 1:-1])  # Horn's weights skip the centre; nodata there is no slope
    dzdx[hole] = np.nan
    return dzdx, dzdy


def slope_degrees(padded: np.ndarray, res: np.ndarray | float) -> np.ndarray:
    """Slope in degrees of the interior of ``padded`` (NaN where the window meets nodata)."""
    dzdx, dzdy = horn_gradient(padded, res)
    return np.degrees(np.arctan(np.hypot(dzdx, dzdy))).astype(np.float32)


def hillshade(padded: np.ndarray, res: np.ndarray | float,
              azimuth: float = 315.0, altitude: float = 45.0) -> np.ndarray:
    """Shaded relief in 0..1: the cosine between the surface normal and the light (from the
    north-west, 45 degrees up by default, as ``gdaldem hillshade``); NaN where the window
    meets nodata."""
    dzdx, dzdy = horn_gradient(padded, res)
    # The surface normal (-dz/dx, -dz/dy, 1) against the unit vector towards the light
    # (east, north, up), azimuth clockwise from north.
    az, alt = np.radians(azimuth), np.radians(altitude)
    light = (np.sin(az) * np.cos(alt), np.cos(az) * np.cos(alt), np.sin(alt))
    shade = (light[2] - dzdx * light[0] - dzdy * light[1]) / np.sqrt(1 + dzdx ** 2 + dzdy ** 2)
    return np.clip(shade, 0.0, 1.0).astype(np.float32)


def slope_colours(degrees: np.ndarray) -> np.ndarray:
    """BGRA image of a slope grid on :data:`SLOPE_STOPS` (transparent where NaN)."""
    stops = np.array([s for s, _ in SLOPE_STOPS])
    colours = np.array([c for _, c in SLOPE_STOPS], np.float64)
    valid = np.isfinite(degrees)
    clean = np.where(valid, degrees, 0.0)
    out = np.zeros((*degrees.shape, 4), np.uint8)
    for channel in range(3):
        out[..., channel] = np.interp(clean, stops, colours[:, channel]).round()
    out[..., 3] = np.where(valid, 255, 0)
    return out


def grey_shade(shade: np.ndarray) -> np.ndarray:
    """BGRA image of a hillshade in 0..1 (transparent where NaN)."""
    valid = np.isfinite(shade)
    grey = np.where(valid, shade * 255.0, 0.0).round().astype(np.uint8)
    return np.dstack([grey, grey, grey, np.where(valid, 255, 0).astype(np.uint8)])


def slope_legend() -> list[dict[str, object]]:
    """The slope ramp for a legend: each stop's degrees and ``#rrggbb`` colour."""
    return [{"degrees": deg, "colour": f"#{r:02x}{g:02x}{b:02x}"}
            for deg, (b, g, r) in SLOPE_STOPS]


def terrarium_encode(heights: np.ndarray) -> np.ndarray:
    """Opaque BGRA image of heights in Terrarium's encoding (1/256 m steps). Nodata (NaN) is
    0 m, the convention of the public Terrarium tiles; never transparent, because a browser
    canvas premultiplies alpha and MapLibre's ``raster-dem`` would read a transparent pixel's
    RGB as 0, 0, 0: -32768 m."""
    valid = np.isfinite(heights)
    # Round to the 1/256 m step once, then split: R * 256 + G + B / 256.
    scaled = np.round((np.where(valid, heights, 0.0) + TERRARIUM_OFFSET) * 256.0)
    steps = np.clip(scaled, 0, 256 ** 3 - 1).astype(np.int64)
    out = np.empty((*heights.shape, 4), np.uint8)
    out[..., 2] = steps >> 16
    out[..., 1] = (steps >> 8) & 0xFF
    out[..., 0] = steps & 0xFF
    out[..., 3] = 255
    return out


def terrarium_decode(rgb: np.ndarray) -> np.ndarray:
    """Heights from an RGB(A) Terrarium image (the client's formula, for checks)."""
    r, g, b = (rgb[..., i].astype(np.float64) for i in range(3))
    return r * 256.0 + g + b / 256.0 - TERRARIUM_OFFSET
