"""A layer as one COG (``ugvmap layers export``) and each source's COG over HTTP (ranges on a
directory store, a presigned redirect on S3)."""

from __future__ import annotations

import uuid
from pathlib import Path

import httpx
import numpy as np
import rasterio
from click.testing import CliRunner
from pyproj import Transformer

from cli.main import main
from ingest.raster.job import ingest_raster
from testkit.raster_synth import UTM33, synthetic_utm, write_tif


def _colour_layer(tmp_path: Path) -> tuple[str, rasterio.Affine]:
    """Red (older) under blue (newer, shifted 60 m south-east): the overlap must be blue, and
    the corner covered by neither stays masked."""
    _, transform = synthetic_utm(tmp_path / "unused.tif", width=10, height=10)
    red = np.zeros((3, 400, 400), np.uint8)
    red[0] = 200
    blue = np.zeros((3, 400, 400), np.uint8)
    blue[2] = 200
    shifted = transform @ rasterio.Affine.translation(200, 200)
    name = f"x-{uuid.uuid4().hex[:8]}"
    ingest_raster([write_tif(tmp_path / "red.tif", red, UTM33, transform)], name)
    ingest_raster([write_tif(tmp_path / "blue.tif", blue, UTM33, shifted)], name)
    return name, transform


def _pixel(ds, transform: rasterio.Affine, col: float, row: float) -> tuple[np.ndarray, int]:
    """The export's value and mask at source pixel (col, row) of the red image."""
    east, north = transform @ (col, row)
    x, y = Transformer.from_crs(UTM33, "EPSG:3857", always_xy=True).transform(east, north)
    r, c = ds.index(x, y)
    window = ((r, r + 1), (c, c + 1))
    return ds.read(window=window)[:, 0, 0], int(ds.read_masks(1, window=window)[0, 0])


def test_export_is_one_cog_in_paint_order(database_url: str, tmp_path: Path) -> None:
    name, transform = _colour_layer(tmp_path)
    out = tmp_path / "layer.tif"
    result = CliRunner().invoke(main, ["layers", "export", name, "--out", str(out)])
    assert result.exit_code == 0, result.output
    with rasterio.open(out) as ds:
        assert ds.crs.to_epsg() == 3857 and ds.count == 3
        assert ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        assert ds.overviews(1)
        red_only, mask = _pixel(ds, transform, 100, 100)
        assert mask == 255 and red_only[0] > 150 > 50 > red_only[2]
        overlap, mask = _pixel(ds, transform, 300, 300)
        assert mask == 255 and overlap[2] > 150 > 50 > overlap[0]  # the newer source on top
        _, outside = _pixel(ds, transform, 500, 100)  # in the extent, in neither image
        assert outside == 0

    for args, message in ((["no-such-layer", "--out", str(out)], "no raster layer"),
                          ([name, "--out", str(tmp_path / "x.png")], "a COG is a .tif"),
                          ([name, "--out", str(tmp_path / "no" / "x.tif")], "no such directory")):
        result = CliRunner().invoke(main, ["layers", "export", *args])
        assert result.exit_code == 1 and message in result.output


def test_source_cog_download_supports_ranges(client, tmp_path: Path) -> None:
    name, _ = _colour_layer(tmp_path)
    sources = client.get(f"/layers/{name}").json()["sources"]
    link = sources[0]["links"]["cog"]
    assert link.endswith(f"/layers/{name}/sources/{sources[0]['id']}.tif")
    whole = client.get(link)
    assert whole.status_code == 200 and whole.headers["content-type"] == "image/tiff"
    assert whole.content[:4] in (b"II*\x00", b"II+\x00")
    part = client.get(link, headers={"Range": "bytes=0-1023"})
    assert part.status_code == 206 and part.content == whole.content[:1024]
    assert client.get(f"/layers/{name}/sources/999999999.tif").status_code == 404
    assert client.get(f"/layers/{name}/sources/abc.tif").status_code == 400


def test_gdal_reads_a_source_cog_in_place_over_http(live_server: str, tmp_path: Path) -> None:
    name, _ = _colour_layer(tmp_path)
    link = httpx.get(f"{live_server}/layers/{name}").json()["sources"][1]["links"]["cog"]
    with rasterio.Env(GDAL_DISABLE_READDIR_ON_OPEN="EMPTY_DIR"), \
            rasterio.open(f"/vsicurl/{link}") as ds:
        assert ds.crs.to_epsg() == 3857
        assert ds.read(3, out_shape=(64, 64)).max() > 150  # the blue source


def test_source_cog_on_s3_redirects_to_a_presigned_url(client, s3_endpoint: str, s3_store: str,
                                                       tmp_path: Path) -> None:
    image, _ = synthetic_utm(tmp_path / "a.tif", width=200, height=200)
    name = f"x-{uuid.uuid4().hex[:8]}"
    ingest_raster([image], name)
    link = client.get(f"/layers/{name}").json()["sources"][0]["links"]["cog"]
    resp = client.get(link, follow_redirects=False)
    assert resp.status_code == 307
    target = resp.headers["location"]
    assert target.startswith(s3_endpoint) and "Signature" in target
    part = httpx.get(target, headers={"Range": "bytes=0-3"})
    assert part.status_code == 206 and part.content in (b"II*\x00", b"II+\x00")
