"""IPM zone mosaics: georeferencing from the zone sidecar, seamless overlap, shared points."""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer

from ingest.raster.georef import GeorefError, ZoneSidecar
from ingest.raster.job import ingest_raster
from testkit.raster_synth import (
    TMS,
    centroid,
    grid_transform,
    lonlat_to_pixel,
    pattern,
    pattern_image,
    stitch,
    write_tif,
)

ORIGIN = {"lat": 48.30, "lon": 15.20}
W, H, OVERLAP, RES = 400, 200, 120, 0.06


def sidecar(row: int, col: int, **extra) -> dict:
    return {"zone": {"row": row, "col": col}, "origin": ORIGIN, "resolution_m": RES,
            "zone_size_px": [W, H], "overlap_px": [OVERLAP, 40], **extra}


def make_zone(tmp_path: Path, row: int, col: int, marker_lonlat: tuple[float, float],
              border_px: int = 0) -> Path:
    """A zone image of the map pattern, a white marker at a map point, a masked black border."""
    doc = sidecar(row, col)
    path = tmp_path / f"zone_r{row}_c{col}.tif"
    (tmp_path / f"zone_r{row}_c{col}.tif.zone.json").write_text(json.dumps(doc))
    zone = ZoneSidecar.load(tmp_path / f"zone_r{row}_c{col}.tif.zone.json")
    transform = zone.transform()
    rgb = pattern_image(transform, W, H)
    # The marker's pixel is worked out from the zone scheme by hand, not from the sidecar code.
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True)
    east0, north0 = to_utm.transform(ORIGIN["lon"], ORIGIN["lat"])
    east, north = to_utm.transform(*marker_lonlat)
    c = round((east - east0) / RES - col * (W - OVERLAP))
    r = round((north0 - north) / RES - row * (H - 40))
    rgb[:, r - 3:r + 3, c - 3:c + 3] = 255
    alpha = np.full((H, W), 255, np.uint8)
    if border_px:  # IPM frames leave black, invalid borders: masked by alpha
        rgb[:, :, :border_px] = 0
        alpha[:, :border_px] = 0
    write_tif(path, rgb, None, None, alpha=alpha)  # georeferenced by the sidecar only
    return path


def marker_point() -> tuple[float, float]:
    """A map point inside the overlap of zones (0, 0) and (0, 1)."""
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True)
    east0, north0 = to_utm.transform(ORIGIN["lon"], ORIGIN["lat"])
    east = east0 + (W - OVERLAP + OVERLAP / 2) * RES
    north = north0 - H / 2 * RES
    return to_utm.transform(east, north, direction="INVERSE")


def test_zone_transform_is_origin_plus_zone_steps() -> None:
    a = ZoneSidecar(row=0, col=0, origin_lat=48.3, origin_lon=15.2, resolution_m=0.06,
                    zone_width_px=28000, zone_height_px=7000, overlap_x_px=4000,
                    overlap_y_px=1000)
    b = ZoneSidecar(**{**a.__dict__, "row": 2, "col": 3})
    assert a.crs().to_epsg() == 32633
    ta, tb = a.transform(), b.transform()
    assert tb.c - ta.c == pytest.approx(3 * 24000 * 0.06)
    assert ta.f - tb.f == pytest.approx(2 * 6000 * 0.06)
    lon, lat = Transformer.from_crs(a.crs().to_wkt(), "EPSG:4326",
                                    always_xy=True).transform(ta.c, ta.f)
    assert (lon, lat) == pytest.approx((15.2, 48.3), abs=1e-9)
    enu = ZoneSidecar(**{**a.__dict__, "frame": "enu"})
    assert (enu.transform().c, enu.transform().f) == pytest.approx((0.0, 0.0), abs=1e-6)
    south = ZoneSidecar(**{**a.__dict__, "origin_lat": -33.9, "origin_lon": 18.4})
    assert south.crs().to_epsg() == 32734


def test_bad_sidecar_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "z.zone.json"
    for doc in ({"zone": {"row": 0}}, sidecar(0, 0, resolution_m=0), sidecar(0, 0, frame="x"),
                {**sidecar(0, 0), "overlap_px": [W, 0]}):
        path.write_text(json.dumps(doc))
        with pytest.raises(GeorefError):
            ZoneSidecar.load(path)


def test_overlapping_zones_mosaic_seamlessly(client, tmp_path: Path) -> None:
    point = marker_point()
    zone_a = make_zone(tmp_path, 0, 0, point)
    zone_b = make_zone(tmp_path, 0, 1, point, border_px=30)
    mosaic, only_a, only_b = (f"z-{uuid.uuid4().hex[:8]}" for _ in range(3))
    ingest_raster([zone_a, zone_b], mosaic, kind="ipm-mosaic")
    ingest_raster([zone_a], only_a, kind="ipm-mosaic")
    ingest_raster([zone_b], only_b, kind="ipm-mosaic")
    info = client.get(f"/layers/{mosaic}").json()
    assert [s["georef"] for s in info["sources"]] == ["zone", "zone"]
    zoom = info["maxzoom"]

    # The shared point lands on the same map coordinate in both zones (and where expected).
    t = TMS.tile(*point, zoom)
    block = (t.x - 1, t.y - 1, 3, 3)
    expected = lonlat_to_pixel(*point, zoom, block[0], block[1])
    for layer in (only_a, only_b, mosaic):
        img = stitch(client.get, layer, zoom, block)
        cx, cy = centroid(img[..., :3].min(axis=2) > 235)
        assert abs(cx - expected[0]) <= 1.0 and abs(cy - expected[1]) <= 1.0, layer

    # Across the whole mosaic: no holes, no black border, content equals the map pattern.
    w, s, e, n = info["bounds"]
    corner_nw, corner_se = TMS.tile(w, n, zoom), TMS.tile(e, s, zoom)
    block = (corner_nw.x, corner_nw.y, corner_se.x - corner_nw.x + 1,
             corner_se.y - corner_nw.y + 1)
    img = stitch(client.get, mosaic, zoom, block)
    transform = grid_transform(zoom, block[0], block[1])
    rows, cols = np.mgrid[0:img.shape[0], 0:img.shape[1]] + 0.5
    mx, my = transform.c + cols * transform.a, transform.f + rows * transform.e
    zone = ZoneSidecar.load(zone_a.with_name(zone_a.name + ".zone.json"))
    east, north = Transformer.from_crs("EPSG:3857", zone.crs().to_wkt(),
                                       always_xy=True).transform(mx, my)
    ta = zone.transform()
    inside = ((east > ta.c + 1) & (east < ta.c + (2 * W - OVERLAP) * RES - 1)
              & (north < ta.f - 1) & (north > ta.f - H * RES + 1))
    assert inside.sum() > 10000
    assert (img[..., 3][inside] == 255).all(), "hole in the mosaic"
    assert (img[..., :3][inside].max(axis=1) > 20).all(), "black border in the mosaic"
    truth = np.moveaxis(pattern(east, north), 0, -1)
    off_marker = inside & (img[..., :3].min(axis=2) < 235)
    err = np.abs(img[..., :3].astype(int) - truth)[off_marker].mean()
    assert err < 2.0
