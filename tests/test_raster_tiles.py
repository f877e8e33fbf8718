"""Raster tiles over HTTP: pixel accuracy, placement, real GDAL client, caching, stacking."""

from __future__ import annotations

import subprocess
import uuid
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
import rasterio
from pyproj import Transformer
from rasterio.transform import from_origin
from sqlalchemy import text

from app.db.session import get_engine
from app.tiles.store import resolve
from ingest.raster.job import ingest_raster
from testkit.raster_synth import (
    TMS,
    UTM33,
    centroid,
    decode_rgba,
    lonlat_to_pixel,
    mae,
    pattern_image,
    reference,
    stitch,
    synthetic_utm,
    tiles_around,
    utm_origin,
    write_tif,
)


def slug() -> str:
    return f"t-{uuid.uuid4().hex[:10]}"


def layer_info(client, name: str) -> dict:
    resp = client.get(f"/layers/{name}")
    assert resp.status_code == 200, resp.text
    return resp.json()


def centre(info: dict) -> tuple[float, float]:
    w, s, e, n = info["bounds"]
    return (w + e) / 2, (s + n) / 2


def test_stitched_tiles_match_source_and_markers_land_within_a_pixel(client, tmp_path) -> None:
    path, transform = synthetic_utm(tmp_path / "synthetic.tif")
    with rasterio.open(path, "r+") as ds:
        data = ds.read()
        # Three white markers at known map coordinates (pattern never exceeds 200).
        markers = [(300, 200), (450, 350), (610, 480)]
        for col, row in markers:
            data[:, row - 4:row + 4, col - 4:col + 4] = 255
        ds.write(data)
    name = slug()
    ingest_raster([path], name)
    info = layer_info(client, name)
    zoom = info["maxzoom"]
    lon, lat = centre(info)
    block = tiles_around(lon, lat, zoom, n=4)
    got = stitch(client.get, name, zoom, block)
    ref = reference(path, zoom, block)
    both = (got[..., 3] == 255) & (ref[..., 3] == 255)
    assert both.mean() > 0.25
    assert mae(got[both][:, :3], ref[both][:, :3]) < 2.0

    to_lonlat = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)
    found = 0
    for col, row in markers:
        east, north = transform @ (col, row)  # the marker's centre (pixel corner col,row)
        mlon, mlat = to_lonlat.transform(east, north)
        px, py = lonlat_to_pixel(mlon, mlat, zoom, block[0], block[1])
        h, w = got.shape[:2]
        if not (20 <= px < w - 20 and 20 <= py < h - 20):
            continue
        window = got[int(py) - 20:int(py) + 20, int(px) - 20:int(px) + 20, :3].min(axis=2)
        cx, cy = centroid(window > 235)
        assert abs(cx - 20 - (px - int(px))) <= 1.0 and abs(cy - 20 - (py - int(py))) <= 1.0
        found += 1
    assert found >= 1


def test_world_file_png_lands_where_the_geotiff_does(client, tmp_path) -> None:
    tif, transform = synthetic_utm(tmp_path / "a.tif", width=400, height=300)
    with rasterio.open(tif) as ds:
        rgb = ds.read()
    png = tmp_path / "a.png"
    import cv2

    cv2.imwrite(str(png), np.moveaxis(rgb[::-1], 0, -1))
    t = transform
    # World file: pixel size, rotations, and the CENTRE of the top-left pixel.
    png.with_suffix(".pgw").write_text(f"{t.a}\n{t.d}\n{t.b}\n{t.e}\n{t.c + t.a / 2}\n"
                                       f"{t.f + t.e / 2}\n")
    a, b = slug(), slug()
    ingest_raster([tif], a)
    ingest_raster([png], b, crs="EPSG:32633")
    info = layer_info(client, a)
    assert layer_info(client, b)["bounds"] == pytest.approx(info["bounds"], abs=1e-9)
    zoom = info["maxzoom"]
    block = tiles_around(*centre(info), zoom, n=2)
    assert mae(stitch(client.get, a, zoom, block), stitch(client.get, b, zoom, block)) < 1.0


def test_real_orthophotos_tiles_match_source(client, shared_data: Path) -> None:
    ortho = shared_data / "orthophotos"
    name = slug()
    paths = [ortho / "pix4d_alpha_nodata.tif", ortho / "webodm_orthophoto.tif"]
    ingest_raster(paths, name, title="drone orthophotos", add=True)  # two continents
    info = layer_info(client, name)
    assert info["source_count"] == 2
    for src in info["sources"]:
        path = ortho / src["name"]
        with rasterio.open(path) as ds:
            bounds = rasterio.warp.transform_bounds(ds.crs, "EPSG:4326", *ds.bounds)
        lon, lat = (bounds[0] + bounds[2]) / 2, (bounds[1] + bounds[3]) / 2
        block = tiles_around(lon, lat, src["zoom"], n=2)
        got = stitch(client.get, name, src["zoom"], block)
        ref = reference(path, src["zoom"], block)
        both = (got[..., 3] == 255) & (ref[..., 3] == 255)
        assert both.mean() > 0.15
        # Real texture costs more under JPEG (q90: ~3.3-3.7 DN on these) than the smooth pattern.
        assert mae(got[both][:, :3], ref[both][:, :3]) < 4.5
        # Outside the valid data the tile is transparent, not black.
        assert (got[..., 3][ref[..., 3] == 0] == 0).mean() > 0.95


def test_gdal_reads_served_tiles_like_the_source(live_server: str, tmp_path) -> None:
    path, _ = synthetic_utm(tmp_path / "g.tif", width=700, height=600)
    name = slug()
    ingest_raster([path], name)
    info = httpx.get(f"{live_server}/layers/{name}").json()
    zoom = info["maxzoom"]
    x0, y0, nx, ny = tiles_around(*centre(info), zoom, n=2)
    wms = tmp_path / "layer.xml"
    wms.write_text(
        "<GDAL_WMS><Service name=\"TMS\">"
        f"<ServerUrl>{live_server}/tiles/{name}/${{z}}/${{x}}/${{y}}.png</ServerUrl></Service>"
        "<DataWindow><UpperLeftX>-20037508.34</UpperLeftX><UpperLeftY>20037508.34</UpperLeftY>"
        "<LowerRightX>20037508.34</LowerRightX><LowerRightY>-20037508.34</LowerRightY>"
        f"<TileLevel>{zoom}</TileLevel><TileCountX>1</TileCountX><TileCountY>1</TileCountY>"
        "<YOrigin>top</YOrigin></DataWindow><Projection>EPSG:3857</Projection>"
        "<BlockSizeX>256</BlockSizeX><BlockSizeY>256</BlockSizeY><BandsCount>4</BandsCount>"
        "<Cache/></GDAL_WMS>")
    out = tmp_path / "out.tif"
    subprocess.run(["gdal_translate", "-q", "-srcwin", str(x0 * 256), str(y0 * 256),
                    str(nx * 256), str(ny * 256), str(wms), str(out)],
                   check=True, env={"GDAL_DEFAULT_WMS_CACHE_PATH": str(tmp_path / "cache")},
                   timeout=60)
    with rasterio.open(out) as ds:
        got = np.moveaxis(ds.read(), 0, -1)
        assert ds.crs.to_epsg() == 3857
    ref = reference(path, zoom, (x0, y0, nx, ny))
    both = (got[..., 3] == 255) & (ref[..., 3] == 255)
    assert both.mean() > 0.5
    assert mae(got[both][:, :3], ref[both][:, :3]) < 2.0


def test_etag_304_and_change_after_reingest_newer_source_on_top(client, tmp_path) -> None:
    _, transform = synthetic_utm(tmp_path / "unused.tif", width=10, height=10)
    red = np.zeros((3, 300, 300), np.uint8)
    red[0] = 200
    blue = np.zeros((3, 300, 300), np.uint8)
    blue[2] = 200
    old = write_tif(tmp_path / "old.tif", red, UTM33, transform)
    new = write_tif(tmp_path / "new.tif", blue, UTM33, transform)
    name = slug()
    ingest_raster([old], name)
    info = layer_info(client, name)
    zoom = info["maxzoom"]
    x0, y0, _, _ = tiles_around(*centre(info), zoom, n=1)
    px, py = (int(v) for v in lonlat_to_pixel(*centre(info), zoom, x0, y0))
    url = f"/tiles/{name}/{zoom}/{x0}/{y0}.png"
    first = client.get(url)
    etag = first.headers["etag"]
    assert "max-age" in first.headers["cache-control"]
    assert decode_rgba(first.content)[py, px, 0] > 150
    assert client.get(url, headers={"If-None-Match": etag}).status_code == 304
    again = client.get(url)
    assert (first.headers["x-tile-cache"], again.headers["x-tile-cache"]) == ("miss", "hit")
    assert again.content == first.content

    ingest_raster([new], name)
    second = client.get(url, headers={"If-None-Match": etag})
    assert second.status_code == 200
    assert second.headers["etag"] != etag
    assert second.headers["x-tile-cache"] == "miss"  # the new version misses the cache
    pixel = decode_rgba(second.content)[py, px]
    assert pixel[2] > 150 and pixel[0] < 50  # the newer (blue) source covers the older one

    # An explicit higher priority wins over recency: the red image again, in place of its
    # first ingest (--replace), at priority 5, then a newer green one at 0: red stays on top.
    ingest_raster([old], name, priority=5, replace=True)
    green = np.zeros((3, 300, 300), np.uint8)
    green[1] = 200
    ingest_raster([write_tif(tmp_path / "green.tif", green, UTM33, transform)], name)
    pixel = decode_rgba(client.get(url).content)[py, px]
    assert pixel[0] > 150 and pixel[1] < 50 and pixel[2] < 50


def test_layers_and_tilejson(client, tmp_path) -> None:
    path, _ = synthetic_utm(tmp_path / "l.tif", width=300, height=200)
    name = slug()
    ingest_raster([path], name, title="Synthetic", kind="ipm-mosaic")
    listed = {la["slug"]: la for la in client.get("/layers").json()["layers"]}
    assert listed[name]["title"] == "Synthetic" and listed[name]["kind"] == "ipm-mosaic"
    tj = client.get(f"/layers/{name}/tilejson.json?format=webp").json()
    assert tj["tilejson"] == "3.0.0"
    assert f"/tiles/{name}/{{z}}/{{x}}/{{y}}.webp?v=" in tj["tiles"][0]
    w, s, e, n = tj["bounds"]
    assert w < tj["center"][0] < e and s < tj["center"][1] < n
    assert tj["minzoom"] <= tj["center"][2] <= tj["maxzoom"]
    with rasterio.open(path) as ds:
        expected = rasterio.warp.transform_bounds(ds.crs, "EPSG:4326", *ds.bounds)
    assert tj["bounds"] == pytest.approx(expected, abs=2e-5)
    x0, y0, _, _ = tiles_around(*centre(listed[name]), tj["maxzoom"], n=1)
    for suffix, media in (("png", "image/png"), ("jpg", "image/jpeg"), ("webp", "image/webp")):
        resp = client.get(f"/tiles/{name}/{tj['maxzoom']}/{x0}/{y0}@2x.{suffix}")
        assert resp.status_code == 200 and resp.headers["content-type"] == media
        assert decode_rgba(resp.content).shape == (512, 512, 4)


def test_tile_errors(client, tmp_path) -> None:
    path, _ = synthetic_utm(tmp_path / "e.tif", width=200, height=200)
    name = slug()
    ingest_raster([path], name)
    assert client.get("/tiles/no-such-layer/3/1/1.png").json()["code"] == "LayerNotFound"
    assert client.get("/layers/no-such-layer").status_code == 404
    assert client.get("/layers/no-such-layer/tilejson.json").status_code == 404
    cases = {f"/tiles/{name}/3/8/1.png": 404, f"/tiles/{name}/3/1/8.png": 404,
             f"/tiles/{name}/31/0/0.png": 404, f"/tiles/{name}/x/1/1.png": 400,
             f"/tiles/{name}/3/-1/1.png": 400, f"/tiles/{name}/3/1/1.gif": 400,
             f"/tiles/{name}/3/1/1": 400, f"/layers/{name}/tilejson.json?format=tiff": 400}
    for url, status in cases.items():
        resp = client.get(url)
        assert resp.status_code == status, url
        assert set(resp.json()) == {"code", "message"}
    # Outside coverage: a transparent PNG, a white JPEG.
    empty = decode_rgba(client.get(f"/tiles/{name}/2/0/0.png").content)
    assert empty[..., 3].max() == 0
    assert decode_rgba(client.get(f"/tiles/{name}/2/0/0.jpg").content)[..., :3].min() > 240


def test_uint16_single_band_and_rgba_sources_render(client, tmp_path) -> None:
    _, transform = synthetic_utm(tmp_path / "unused.tif", width=10, height=10)
    gray = np.tile(np.linspace(1000, 3000, 256, dtype=np.uint16), (256, 1))[None]
    rgb = pattern_image(transform, 256, 256)
    alpha = np.full((256, 256), 255, np.uint8)
    alpha[:, :128] = 0  # left half transparent
    a, b = slug(), slug()
    ingest_raster([write_tif(tmp_path / "g16.tif", gray, UTM33, transform)], a)
    ingest_raster([write_tif(tmp_path / "rgba.tif", rgb, UTM33, transform, alpha=alpha)], b)
    info = layer_info(client, a)
    block = tiles_around(*centre(info), info["maxzoom"], n=1)
    tile = stitch(client.get, a, info["maxzoom"], block)
    valid = tile[..., 3] == 255
    assert valid.mean() > 0.2
    row = tile[valid.any(axis=1).nonzero()[0][len(valid.any(axis=1).nonzero()[0]) // 2]]
    vals = row[row[:, 3] == 255][:, 0].astype(int)
    assert vals[-1] - vals[0] > 100  # the uint16 ramp is stretched into 8 bits, increasing
    info_b = layer_info(client, b)
    west, _, east, _ = info_b["bounds"]
    full_w = rasterio.warp.transform_bounds(UTM33, "EPSG:4326", transform.c, transform.f - 76.8,
                                            transform.c + 76.8, transform.f)
    assert west == pytest.approx((full_w[0] + full_w[2]) / 2, abs=(east - west) * 0.05)


def test_low_zoom_tiles_come_from_the_layer_overview(client, tmp_path) -> None:
    from app.tiles.cache import tile_cache
    from app.tiles.catalog import TileSource
    from app.tiles.mosaic import render
    from app.tiles.readers import overview_zoom

    # Flat colours: at overview zooms the test pattern itself would alias.
    east, north = utm_origin()
    a = write_tif(tmp_path / "a.tif", np.array([200, 40, 40], np.uint8).reshape(3, 1, 1)
                  * np.ones((1, 1200, 1500), np.uint8), UTM33,
                  from_origin(east, north, 0.3, 0.3))
    b = write_tif(tmp_path / "b.tif", np.array([40, 40, 200], np.uint8).reshape(3, 1, 1)
                  * np.ones((1, 1200, 1500), np.uint8), UTM33,
                  from_origin(east + 300, north - 200, 0.3, 0.3))
    name = slug()
    ingest_raster([a], name)
    ingest_raster([b], name)
    info = layer_info(client, name)
    with get_engine().connect() as conn:
        overview = conn.execute(text("SELECT overview_uri FROM layers WHERE slug = :s"),
                                {"s": name}).scalar()
        uris = list(conn.execute(text(
            "SELECT uri FROM raster_sources s JOIN layers l ON l.id = s.layer_id "
            "WHERE l.slug = :s ORDER BY s.ingested_at, s.id"), {"s": name}).scalars())
    overview, uris = resolve(overview), [resolve(u) for u in uris]
    zoom = overview_zoom(overview)
    assert 0 < zoom <= info["maxzoom"] - 5
    assert len(list(Path(overview).parent.glob("overview-*.tif"))) == 1  # old one replaced
    x0, y0, _, _ = tiles_around(*centre(info), zoom, n=1)
    url = f"/tiles/{name}/{zoom}/{x0}/{y0}.png"
    tile = decode_rgba(client.get(url).content)
    # Same picture as composing the sources directly...
    bounds = TMS.xy_bounds(x0, y0, zoom)
    direct = render([TileSource(uri, None) for uri in uris],
                    (bounds.left, bounds.bottom, bounds.right, bounds.top), 256)
    direct = direct[..., [2, 1, 0, 3]]
    both = (tile[..., 3] == 255) & (direct[..., 3] == 255)
    # JPEG (4:2:0 chroma) bleeds a few pixels at data and colour edges; compare the interior.
    both = cv2.erode(both.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    err = np.abs(tile[both][:, :3].astype(int) - direct[both][:, :3]).max(axis=1)
    assert both.sum() > 50 and np.median(err) <= 6
    assert (tile[both][:, 0] > 150).any() and (tile[both][:, 2] > 150).any()  # both sources
    # ...but read from the overview alone: hiding the sources does not change it.
    for uri in uris:
        Path(uri).rename(uri + ".hidden")
    tile_cache.cache_clear()  # render again, not from the tile cache
    try:
        assert np.array_equal(decode_rgba(client.get(url).content), tile)
        # A zoom the sources serve: their files are gone, which is an error, not a blank.
        fine = tiles_around(*centre(info), info["maxzoom"], n=1)
        missing = client.get(f"/tiles/{name}/{info['maxzoom']}/{fine[0]}/{fine[1]}.png")
        assert (missing.status_code, missing.json()["code"]) == (500, "RasterSourceMissing")
    finally:
        for uri in uris:
            Path(uri + ".hidden").rename(uri)


def test_layer_zoom_range_spans_all_sources(client, tmp_path) -> None:
    coarse, _ = synthetic_utm(tmp_path / "coarse.tif", width=300, height=300, res=2.4)
    fine, _ = synthetic_utm(tmp_path / "fine.tif", width=300, height=300, res=0.15)
    name = slug()
    ingest_raster([coarse], name)
    first = layer_info(client, name)
    ingest_raster([fine], name)
    both = layer_info(client, name)
    zooms = [s["zoom"] for s in both["sources"]]
    assert zooms[1] - zooms[0] == 4  # 2.4 m vs 0.15 m is 16x, four zoom levels
    assert both["maxzoom"] == zooms[1] and both["minzoom"] == first["minzoom"]
