"""Elevation layers: ingest of DEMs (any CRS, int or float, nodata), Terrarium tiles that
decode to the stored heights, slope that agrees with ``gdaldem slope``, hillshade, heights at
points over HTTP, and bad input refused in our words."""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer
from rasterio.transform import from_origin
from sqlalchemy import text

from app.db.session import get_engine
from app.terrain.relief import hillshade, slope_degrees, terrarium_decode, terrarium_encode
from ingest.raster.job import ingest_raster
from ingest.raster.sources import SourceError
from testkit.raster_synth import TMS, UTM33, decode_rgba, grid_transform, utm_origin, write_tif
from testkit.terrain_checks import slope_tiles_vs_gdaldem
from testkit.terrain_synth import hills, plane, write_dem

SRTM = Path(__file__).resolve().parents[1].parent / "shared/data/terrain/topotoolbox_srtm30m/" \
    "srtm_bigtujunga30m_utm11.tif"


def slug() -> str:
    return f"dem-{uuid.uuid4().hex[:10]}"


def test_terrarium_round_trips_heights_to_a_256th_of_a_metre() -> None:
    heights = np.array([[-412.37, 0.0, 8848.86], [1086.2, np.nan, 0.004]])
    decoded = terrarium_decode(terrarium_encode(heights)[..., [2, 1, 0]])
    valid = np.isfinite(heights)
    assert np.abs(decoded[valid] - heights[valid]).max() <= 1 / 512 + 1e-9
    assert decoded[1, 1] == 0.0  # nodata is 0 m, the public tiles' convention


def test_slope_and_hillshade_of_a_plane_are_the_analytic_ones() -> None:
    _, cols = np.mgrid[0:12, 0:12]
    res = 2.0
    z = 100 + 0.5 * cols * res  # rises 0.5 m per m to the east: 26.57 degrees
    assert np.allclose(slope_degrees(z, res), np.degrees(np.arctan(0.5)), atol=1e-4)
    # Facing west, lit from the north-west: the normal (-0.5, 0, 1) against the light.
    light = np.array([-np.sin(np.radians(45)) * np.cos(np.radians(45)),
                      np.cos(np.radians(45)) ** 2, np.sin(np.radians(45))])
    expected = np.dot([-0.5, 0, 1], light) / np.sqrt(1.25)
    assert np.allclose(hillshade(z, res), expected, atol=1e-5)
    holed = z.astype(float)
    holed[5, 5] = np.nan
    holed_slope = slope_degrees(holed, res)  # the padded (5, 5) is the output's (4, 4)
    assert np.isnan(holed_slope[3:6, 3:6]).all() and np.isfinite(holed_slope[0, 0])


def _ingest_terrarium_grid(tmp_path: Path, zoom: int) -> tuple[str, np.ndarray, tuple[int, int]]:
    """A float DEM written exactly on the tile grid of ``zoom`` (3 x 2 tiles), ingested."""
    tile = TMS.tile(-87.16, 14.08, zoom)
    transform = grid_transform(zoom, tile.x, tile.y)
    surface = hills((transform.c, transform.f))
    path = tmp_path / "grid.tif"
    heights = write_dem(path, surface, "EPSG:3857", transform, 768, 512, hole=(
        slice(40, 60), slice(300, 340)))
    name = slug()
    ingest_raster([path], name, kind="elevation")
    return name, heights, (tile.x, tile.y)


def test_terrarium_tiles_decode_to_the_dem_within_a_centimetre(client, tmp_path) -> None:
    zoom = 18
    name, heights, (x0, y0) = _ingest_terrarium_grid(tmp_path, zoom)
    layer = client.get(f"/layers/{name}").json()
    assert layer["kind"] == "elevation" and layer["maxzoom"] == zoom
    assert "render=terrarium" in layer["renders"]["terrarium"]["tiles"]
    worst = 0.0
    for dy in range(2):
        for dx in range(3):
            resp = client.get(f"/tiles/{name}/{zoom}/{x0 + dx}/{y0 + dy}.png?render=terrarium")
            assert resp.status_code == 200 and resp.headers["content-type"] == "image/png"
            got = terrarium_decode(decode_rgba(resp.content))
            want = heights[dy * 256:(dy + 1) * 256, dx * 256:(dx + 1) * 256]
            valid = want != -9999
            worst = max(worst, float(np.abs(got[valid] - want[valid]).max()))
            assert (got[~valid] == 0).all()
    assert worst <= 0.01
    # Terrarium is lossless only: a JPEG of heights would be wrong heights.
    resp = client.get(f"/tiles/{name}/{zoom}/{x0}/{y0}.jpg?render=terrarium")
    assert resp.status_code == 400 and "lossless PNG" in resp.json()["message"]


def _slope_tiles_vs_gdaldem(dem: Path, tmp_path: Path, name: str) -> float:
    with get_engine().connect() as conn:
        median, compared = slope_tiles_vs_gdaldem(conn, name, dem, tmp_path)
    assert compared > 10_000
    return median


def test_slope_tiles_agree_with_gdaldem_on_a_utm_dem(database_url, tmp_path) -> None:
    origin = utm_origin()
    transform = from_origin(round(origin[0]), round(origin[1]), 2.0, 2.0)
    path = tmp_path / "hills-utm.tif"
    write_dem(path, hills((transform.c, transform.f - 300)), UTM33, transform, 300, 300,
              dtype="int16", nodata=-32768, hole=(slice(100, 130), slice(50, 90)))
    name = slug()
    ingest_raster([path], name, kind="elevation")
    assert _slope_tiles_vs_gdaldem(path, tmp_path, name) <= 0.5


@pytest.mark.skipif(not SRTM.is_file(), reason=f"{SRTM} (shared terrain data) is absent")
def test_slope_tiles_agree_with_gdaldem_on_srtm(database_url, tmp_path) -> None:
    name = slug()
    ingest_raster([SRTM], name, kind="elevation")
    assert _slope_tiles_vs_gdaldem(SRTM, tmp_path, name) <= 0.5


def test_hillshade_and_slope_tiles_and_plain_tiles_of_an_elevation_layer(client,
                                                                          tmp_path) -> None:
    zoom = 18
    name, _, (x0, y0) = _ingest_terrarium_grid(tmp_path, zoom)
    plain = client.get(f"/tiles/{name}/{zoom}/{x0}/{y0}.png")
    shade = client.get(f"/tiles/{name}/{zoom}/{x0}/{y0}.png?render=hillshade")
    assert plain.status_code == shade.status_code == 200
    assert plain.content == shade.content  # an elevation layer's plain tile is its hillshade
    grey = decode_rgba(shade.content)
    assert (grey[..., 0] == grey[..., 1]).all() and grey[..., 0].std() > 10
    slope = decode_rgba(client.get(f"/tiles/{name}/{zoom}/{x0}/{y0}.png?render=slope").content)
    assert slope[..., 3].mean() > 200 and (slope[..., 0] != slope[..., 1]).any()
    legend = client.get(f"/layers/{name}").json()["renders"]["slope_legend"]
    assert legend[0] == {"degrees": 0.0, "colour": "#1ac860"}
    # Low zooms read the layer overview, which keeps heights (not colours).
    low = client.get(f"/tiles/{name}/12/{x0 >> 6}/{y0 >> 6}.png?render=terrarium")
    decoded = terrarium_decode(decode_rgba(low.content))
    assert 250 < decoded.max() < 420
    bad = client.get(f"/tiles/{name}/{zoom}/{x0}/{y0}.png?render=contours")
    assert bad.status_code == 400 and "hillshade, slope, terrarium" in bad.json()["message"]


def test_heights_at_points_are_bilinear_and_null_outside_or_on_nodata(client, tmp_path) -> None:
    origin = utm_origin(15.25, 48.31)
    transform = from_origin(round(origin[0]), round(origin[1]), 1.0, 1.0)
    surface = plane((transform.c, transform.f), 0.05, -0.02, 500.0)
    path = tmp_path / "plane.tif"
    write_dem(path, surface, UTM33, transform, 400, 400, hole=(slice(200, 260), slice(0, 60)))
    name = slug()
    ingest_raster([path], name, kind="elevation")
    to_lonlat = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)
    inside = [(transform.c + 100.3, transform.f - 50.7), (transform.c + 333.0, transform.f - 390)]
    hole = (transform.c + 30, transform.f - 230)
    outside = (transform.c - 500, transform.f)
    pts = [to_lonlat.transform(*p) for p in [*inside, hole, outside]]
    resp = client.get(f"/layers/{name}/elevation",
                      params={"points": ";".join(f"{lon:.8f},{lat:.8f}" for lon, lat in pts)})
    assert resp.status_code == 200, resp.text
    heights = resp.json()["heights"]
    for (e, n), h in zip(inside, heights, strict=False):
        assert h == pytest.approx(float(surface(np.array(e), np.array(n))), abs=0.02)
    assert heights[2:] == [None, None]
    ortho = client.get("/layers/nope-none/elevation", params={"points": "1,2"})
    assert ortho.status_code == 404


def test_bad_dems_are_refused_in_our_words_and_nothing_is_stored(database_url, tmp_path) -> None:
    name = slug()
    no_crs = tmp_path / "no-crs.tif"
    write_dem(no_crs, hills((0, 0)), None, from_origin(500000, 5000000, 1, 1), 50, 50)
    with pytest.raises(SourceError, match=r"no-crs\.tif: not georeferenced"):
        ingest_raster([no_crs], name, kind="elevation")
    empty = tmp_path / "all-nodata.tif"
    origin = utm_origin()
    write_dem(empty, hills(origin), UTM33, from_origin(*origin, 1, 1), 50, 50,
              hole=(slice(None), slice(None)))
    with pytest.raises(SourceError, match=r"all-nodata\.tif: no valid pixels"):
        ingest_raster([empty], name, kind="elevation")
    picture = write_tif(tmp_path / "photo.tif", np.zeros((3, 20, 20), np.uint8), UTM33,
                        from_origin(*origin, 1, 1))
    with pytest.raises(SourceError, match=r"heights in one band; this file has 3 colour bands"):
        ingest_raster([picture], name, kind="elevation")
    with get_engine().connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM layers WHERE slug = :s"),
                            {"s": name}).scalar() == 0


def test_lanelet2_and_package_take_ele_from_an_elevation_layer(database_url, tmp_path) -> None:
    import json
    import xml.etree.ElementTree as ET

    from click.testing import CliRunner

    from app.db.session import session_scope
    from cli.main import main
    from ingest.network import RoadAttributes, RoadLine, write_network

    origin = utm_origin(15.35, 48.45)
    transform = from_origin(round(origin[0]), round(origin[1]), 1.0, 1.0)
    surface = plane((transform.c, transform.f), 0.04, 0.01, 612.0)
    write_dem(tmp_path / "plane.tif", surface, UTM33, transform, 300, 300)
    name = slug()
    ingest_raster([tmp_path / "plane.tif"], name, kind="elevation")
    to_lonlat = Transformer.from_crs(UTM33, "EPSG:4326", always_xy=True)
    road = [to_lonlat.transform(transform.c + e, transform.f - n) for e, n in
            [(50, 150), (150, 140), (250, 160)]]
    net = f"ele-{uuid.uuid4().hex[:8]}"
    with session_scope() as session:
        write_network(session, net, [RoadLine(road, RoadAttributes(1, 1, 30.0))])
    to_utm = Transformer.from_crs("EPSG:4326", UTM33, always_xy=True)

    def eles(osm: Path) -> tuple[np.ndarray, np.ndarray]:
        nodes = ET.parse(osm).getroot().findall("node")
        lon = np.array([float(n.get("lon")) for n in nodes])
        lat = np.array([float(n.get("lat")) for n in nodes])
        got = np.array([float(n.find("tag[@k='ele']").get("v")) for n in nodes])
        e, n = to_utm.transform(lon, lat)
        return got, surface(np.asarray(e), np.asarray(n))

    runner = CliRunner()
    out = runner.invoke(main, ["export", "network", net, "--format", "lanelet2", "--out",
                               str(tmp_path / "map.osm"), "--elevation-layer", name])
    assert out.exit_code == 0, out.output
    got, truth = eles(tmp_path / "map.osm")
    assert len(got) > 4 and np.abs(got - truth).max() < 0.05  # lanes are within the DEM
    flat = runner.invoke(main, ["export", "network", net, "--format", "lanelet2", "--out",
                                str(tmp_path / "flat.osm")])
    assert flat.exit_code == 0 and (eles(tmp_path / "flat.osm")[0] == 0).all()
    wrong = runner.invoke(main, ["export", "network", net, "--format", "geojson", "--out",
                                 str(tmp_path / "x.geojson"), "--elevation-layer", name])
    assert wrong.exit_code == 1 and "lanelet2 only" in wrong.output

    w, s = (min(p[i] for p in road) - 0.001 for i in (0, 1))
    e, n = (max(p[i] for p in road) + 0.001 for i in (0, 1))
    pkg = runner.invoke(main, ["export", "package", "--bbox", f"{w},{s},{e},{n}", "--network",
                               net, "--out", str(tmp_path / "pkg"), "--elevation-layer", name])
    assert pkg.exit_code == 0, pkg.output
    manifest = json.loads((tmp_path / "pkg" / "manifest.json").read_text())
    assert manifest["network"]["lanelet2"]["ele"] == f"heights of elevation layer {name}"
    got, truth = eles(tmp_path / "pkg" / "lanelet2" / "lanelet2_map.osm")
    assert np.abs(got - truth).max() < 0.05
    not_heights = runner.invoke(main, ["export", "package", "--bbox", f"{w},{s},{e},{n}",
                                       "--network", net, "--out", str(tmp_path / "pkg2"),
                                       "--elevation-layer", "no-such-layer"])
    assert not_heights.exit_code == 1 and "no raster layer" in not_heights.output
    assert not (tmp_path / "pkg2").exists()
