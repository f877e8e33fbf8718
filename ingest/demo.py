"""``ugvmap demo``: load the sample data ``make demo`` opens onto.

With the shared samples present (``../shared/data``): the SpaceNet Las Vegas image as a layer
with its road labels imported as a routable network over it, the same roads extracted from the
image by the road model, zero-shot (to compare with the labels on the map), the drone
orthophotos, and the Helsinki OSM extract as a larger routable network. Without them, a
synthetic town is rendered, georeferenced, ingested and its roads extracted (by the spectral
line: a rendering is not a photograph), so the demo still shows every capability.
Every step is skipped when its layer / network already exists, so re-running is cheap.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
from rasterio.transform import from_origin
from sqlalchemy import text

from app.db.session import session_scope
from app.tiles.catalog import layer_row
from ingest.network import import_network
from ingest.raster.job import ingest_raster
from ingest.raster.samples import ingest_sample_orthophotos
from ingest.roads.layer import ingest_layer_roads
from ingest.roads.pipeline import Classifier, ExtractParams
from ingest.roads.sample import GeoSample
from ingest.roads.synthetic import grid_scene, render

Say = Callable[[str], None]
VEGAS = Path("road_imagery/spacenet_vegas")
VEGAS_IMAGE = VEGAS / "RGB-PanSharpen_AOI_2_Vegas_img0.tif"
VEGAS_LABELS = VEGAS / "AOI_2_Vegas_img0.geojson"
HELSINKI = Path("osm/Helsinki.osm.pbf")
SYNTHETIC_ORIGIN = (-115.1690, 36.2400)  # lon/lat of the synthetic town's north-west corner


def _layer_exists(slug: str, say: Say) -> bool:
    with session_scope() as session:
        found = layer_row(session.connection(), slug) is not None
    if found:
        say(f"layer {slug}: already there")
    return found


def _network_exists(name: str) -> bool:
    with session_scope() as session:
        return bool(session.execute(
            text("SELECT 1 FROM networks WHERE name = :n"), {"n": name}).first())


def _layer(slug: str, paths: list[Path], title: str, say: Say) -> None:
    ingest_raster(paths, slug, title=title)
    say(f"layer {slug}: ingested")


def _network(name: str, path: Path, say: Say) -> None:
    if _network_exists(name):
        say(f"network {name}: already there")
        return
    with session_scope() as session:
        summary = import_network(session, path, name)
    say(f"network {name}: {summary.segments} segments imported from {path.name}")


def _extracted(name: str, layer: str, say: Say, sample: GeoSample | None = None,
               classifier: Classifier = "auto") -> None:
    """By default the road model, zero-shot: what a user gets from a new layer with no
    labels at all."""
    if _network_exists(name):
        say(f"network {name}: already there")
        return
    with session_scope() as session:
        done = ingest_layer_roads(session, layer, name, sample,
                                  ExtractParams(classifier=classifier))
    say(f"network {name}: {done.summary.segments} segments extracted from layer {layer}")


def load_shared(data: Path, say: Say) -> None:
    """Load the demo from the shared samples (each step skipped when already there)."""
    if not _layer_exists("vegas", say):
        _layer("vegas", [data / VEGAS_IMAGE], "SpaceNet Las Vegas (WorldView-3)", say)
    _network("vegas", data / VEGAS_LABELS, say)
    _extracted("vegas-extracted", "vegas", say)
    for report in ingest_sample_orthophotos(data / "orthophotos"):
        say(f"layer {report.layer}: ingested")
    _network("helsinki", data / HELSINKI, say)


def load_synthetic(say: Say) -> None:
    """A rendered 1 km town at 0.5 m/px, georeferenced in UTM 11N near Las Vegas."""
    from pyproj import Transformer

    utm = "EPSG:32611"
    east, north = Transformer.from_crs("EPSG:4326", utm, always_xy=True).transform(
        *SYNTHETIC_ORIGIN)
    res, size, spacing = 0.5, 2000, 250
    transform = from_origin(round(east), round(north), res, res)
    if not _layer_exists("synthetic-town", say):
        import rasterio

        rgb, _ = render(grid_scene(size, spacing, 14, seed=7))
        with tempfile.TemporaryDirectory(prefix="ugvmap-demo-") as tmp:
            path = Path(tmp) / "synthetic-town.tif"
            with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=3,
                               dtype="uint8", crs=utm, transform=transform) as ds:
                ds.write(np.moveaxis(rgb, -1, 0))
            _layer("synthetic-town", [path], "Synthetic town (generated)", say)
    # A rendered town is not aerial imagery: its flat grey-on-green roads are the survey's
    # spectral line's ideal case, and a model trained on photographs breaks them at roofs.
    to_lonlat = Transformer.from_crs(utm, "EPSG:4326", always_xy=True).transform
    row = spacing // 2  # a horizontal road; sample 40 m of it
    (lon0, lat1), (lon1, lat0) = (to_lonlat(*(transform @ (x, y)))
                                  for x, y in ((200, row - 4), (280, row + 4)))
    _extracted("synthetic-town", "synthetic-town", say,
               GeoSample(road_boxes=[(lon0, lat0, lon1, lat1)]), "spectral")


def demo_token(path: Path) -> str:
    """The demo's editor token, kept in ``.data`` (the store keeps only its hash).

    A token file left from another database (a reset ``.data``, a different DATABASE_URL)
    is replaced rather than printed, since it would not authenticate here.
    """
    from app.network.tokens import create_token, hash_token

    with session_scope() as session:
        if path.is_file():
            token = path.read_text().strip()
            if session.execute(text("SELECT 1 FROM api_tokens WHERE token_hash = :h "
                                    "AND revoked_at IS NULL"), {"h": hash_token(token)}).first():
                return token
        token = create_token(session, "demo-editor", "editor")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(token + "\n")
    path.chmod(0o600)
    return token


def load_demo(shared_data: Path, token_file: Path, say: Say) -> str:
    """Load the demo (shared samples, or the synthetic town without them) and return an editor token
    for the web map."""
    if (shared_data / VEGAS_IMAGE).is_file():
        load_shared(shared_data, say)
    else:
        say(f"{shared_data} not found: generating a synthetic town instead")
        load_synthetic(say)
    return demo_token(token_file)
