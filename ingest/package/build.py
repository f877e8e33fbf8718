"""Build an offline mission package for an area: everything a vehicle needs with no link.

Layout of the folder (or of the .zip, the same tree)::

    manifest.json                       what is inside: versions, bbox, CRSs, zooms, checksums
    rasters/<layer>.mbtiles             each raster layer's served PNG tiles in the area
    network/<network>.gpkg              the network's segments and nodes meeting the area
    network/<network>.mbtiles           its vector tiles (z12+, as served) for a map display
    lanelet2/lanelet2_map.osm           the lane-level map, and beside it
    lanelet2/map_projector_info.yaml    its origin, as Autoware's map loader reads it

The network is *clipped* by keeping the whole segments that meet the area (none is cut, so
segment ids, lengths and the Lanelet2 ``segment_id`` tags stay the network's, and the vehicle
can drive to the area's edge). Tiles are rendered by the same code that serves them, so each
archived tile equals the served tile byte for byte. The package is built in a temporary folder
next to the output and appears complete or not at all.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from importlib.metadata import version
from pathlib import Path
from typing import Any

import morecantile
from sqlalchemy import Connection, text
from sqlalchemy.orm import Session

from app.errors import UserError
from app.grid import MAX_ZOOM, tile_bounds
from app.lanelet2.export import PROJECTOR_FILE, Lanelet2Export, write_lanelet2
from app.lanelet2.roads import AREA_WHERE, read_selection
from app.network import tilejson
from app.network.summary import integer_ranges
from app.network.tiles import NODES_MINZOOM, render_tile
from app.terrain.heights import ground
from app.tiles import catalog
from app.tiles.mosaic import compose_tile
from ingest.network.exporter import load_network, write_gpkg
from ingest.package.mbtiles import MBTilesWriter

Bbox = tuple[float, float, float, float]
Progress = Callable[[str, float], None]
TMS = morecantile.tms.get("WebMercatorQuad")
NETWORK_MAXZOOM = 16  # network vector tiles: z12 (every segment) to z16, overzoomed beyond
FORMAT = "ugvmap-mission-package"
FORMAT_VERSION = 1


@dataclass
class LayerPlan:
    """One raster layer's part of the package."""

    slug: str
    title: str
    version: int
    minzoom: int
    maxzoom: int
    bounds: Bbox  # the layer's data within the package area
    tiles: list[morecantile.Tile]
    stored: int = 0


@dataclass
class PackagePlan:
    """What a package will hold, checked before anything is written."""

    bbox: Bbox
    network: str
    network_id: int
    segments: int
    layers: list[LayerPlan]
    network_tiles: list[morecantile.Tile] = field(default_factory=list)
    elevation_layer: str | None = None  # whose heights are the Lanelet2 map's ele

    @property
    def tile_count(self) -> int:
        """Raster and vector tiles to render."""
        return sum(len(layer.tiles) for layer in self.layers) + len(self.network_tiles)


def _zooms(layer: dict[str, Any], minzoom: int | None, maxzoom: int | None) -> range:
    lo = layer["minzoom"] if minzoom is None else minzoom
    hi = layer["maxzoom"] if maxzoom is None else maxzoom
    if not 0 <= lo <= hi <= MAX_ZOOM:
        raise UserError(f"zooms {lo}..{hi} for layer {layer['slug']!r}: need 0 <= minzoom <= "
                        f"maxzoom <= {MAX_ZOOM} (the layer has {layer['minzoom']}.."
                        f"{layer['maxzoom']})")
    return range(lo, hi + 1)


def _overlap(a: Bbox, b: Bbox) -> Bbox | None:
    w, s, e, n = max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3])
    return (w, s, e, n) if w < e and s < n else None


def plan_package(conn: Connection, bbox: Bbox, layers: list[str], network: str, *,
                 minzoom: int | None = None, maxzoom: int | None = None,
                 max_tiles: int = 200_000, elevation_layer: str | None = None) -> PackagePlan:
    """Check the request against the store (network and layers exist and have data in the
    area, zooms make sense, the tile count is within ``max_tiles``) and list every tile."""
    row = conn.execute(text(
        "SELECT n.id, (SELECT count(*) FROM road_segments s WHERE s.network_id = n.id "
        f"{AREA_WHERE}) FROM networks n WHERE n.name = :name"),
        {"name": network, **dict(zip("wsen", bbox, strict=True))}).first()
    if row is None:
        raise UserError(f"network {network[:100]!r} does not exist")
    if row[1] == 0:
        raise UserError(f"network {network!r} has no segments within bbox "
                        f"{','.join(map(str, bbox))}: the area is outside its data")
    plans = []
    for slug in layers:
        layer = catalog.layer_row(conn, slug)
        if layer is None:
            raise UserError(f"no raster layer {slug[:100]!r}")
        covered = _overlap(bbox, tuple(layer["bounds"])) if layer["bounds"] else None
        if covered is None:
            raise UserError(f"layer {slug!r} has no data within bbox "
                            f"{','.join(map(str, bbox))} (its data covers "
                            f"{','.join(f'{v:.6f}' for v in layer['bounds'] or [])})")
        zooms = _zooms(layer, minzoom, maxzoom)
        plans.append(LayerPlan(slug, layer["title"], layer["version"], zooms.start,
                               zooms.stop - 1, covered, list(TMS.tiles(*covered, zooms=zooms))))
    hi = max([p.maxzoom for p in plans], default=NETWORK_MAXZOOM)
    network_zooms = range(NODES_MINZOOM, min(hi, NETWORK_MAXZOOM) + 1)
    if elevation_layer:
        ground(conn, elevation_layer)  # refused now (unknown, not heights), not mid-package
    plan = PackagePlan(bbox, network, row[0], row[1], plans,
                       list(TMS.tiles(*bbox, zooms=network_zooms)), elevation_layer)
    if plan.tile_count > max_tiles:
        per_layer = ", ".join(f"{p.slug} z{p.minzoom}-{p.maxzoom}: {len(p.tiles)}" for p in plans)
        raise UserError(f"the package would hold {plan.tile_count} tiles ({per_layer}, network "
                        f"{len(plan.network_tiles)}), more than --max-tiles {max_tiles}: lower "
                        "--maxzoom or the area")
    return plan


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _tile_extent(tiles: list[morecantile.Tile]) -> Bbox:
    """Lon/lat extent of whole tiles: an archive's ``bounds`` on the tile grid, so GDAL's
    raster of it lines up with the tiles' pixels (no resampling when it reads them)."""
    boxes = [TMS.bounds(t) for t in tiles]
    return (min(b.left for b in boxes), min(b.bottom for b in boxes),
            max(b.right for b in boxes), max(b.top for b in boxes))


def _raster_archive(conn: Connection, layer: LayerPlan, path: Path, tick: Callable[[], None]
                    ) -> None:
    w, s, e, n = _tile_extent([t for t in layer.tiles if t.z == layer.maxzoom])
    metadata = {"name": layer.title or layer.slug, "format": "png", "type": "overlay",
                "version": str(layer.version), "minzoom": str(layer.minzoom),
                "maxzoom": str(layer.maxzoom), "bounds": f"{w:.7f},{s:.7f},{e:.7f},{n:.7f}",
                "center": f"{(w + e) / 2:.7f},{(s + n) / 2:.7f},{layer.maxzoom}",
                "description": f"ugvmap raster layer {layer.slug}, version {layer.version}"}
    with MBTilesWriter(path, metadata) as archive:
        for tile in layer.tiles:
            query = catalog.tile_sources(conn, layer.slug, tile_bounds(tile.z, tile.x, tile.y))
            if query is not None and query.sources:  # elsewhere the server sends an empty tile
                archive.add(tile.z, tile.x, tile.y,
                            compose_tile(query, tile.z, tile.x, tile.y, "png"))
            tick()
        layer.stored = archive.count


def _network_archive(session: Session, plan: PackagePlan, version_: int, path: Path,
                     tick: Callable[[], None]) -> int:
    w, s, e, n = plan.bbox
    zooms = [t.z for t in plan.network_tiles] or [NODES_MINZOOM]
    metadata = tilejson.mbtiles_metadata(
        tilejson.NetworkInfo(plan.network, None, None, version_, [w, s, e, n]),
        integer_ranges(session, plan.network_id))
    metadata |= {"minzoom": str(min(zooms)), "maxzoom": str(max(zooms))}
    with MBTilesWriter(path, metadata) as archive:
        for tile in plan.network_tiles:
            body = render_tile(session, plan.network_id, tile.z, tile.x, tile.y)
            if body:
                archive.add(tile.z, tile.x, tile.y, body)
            tick()
        return archive.count


@dataclass(frozen=True)
class PackageResult:
    """Where the package is and what its manifest says."""

    path: Path
    manifest: dict[str, Any]
    lanelet2: Lanelet2Export


def build_package(session: Session, plan: PackagePlan, out: Path,
                  progress: Progress | None = None) -> PackageResult:
    """Write the package of ``plan`` to ``out`` (a folder, or a ``.zip``); the session should
    be REPEATABLE READ so every part shows the same network version."""
    say: Progress = progress or (lambda _m, _f: None)
    as_zip = out.suffix.lower() == ".zip"
    empty_folder = out.is_dir() and not as_zip and not any(out.iterdir())
    if out.exists() and not empty_folder:
        raise UserError(f"{out} already exists: give a new folder or .zip")
    if not out.parent.is_dir():
        raise UserError(f"{out.parent} is not a directory")
    work = out.with_name(f".{out.name}.part")
    shutil.rmtree(work, ignore_errors=True)
    conn = session.connection()
    try:
        for sub in ("rasters", "network", "lanelet2"):
            (work / sub).mkdir(parents=True)
        total = plan.tile_count + 2
        done = 0

        def tick() -> None:
            nonlocal done
            done += 1
            if done % 50 == 0 or done == total:
                say("tiles", 0.9 * done / total)

        version_ = int(conn.execute(text("SELECT version FROM networks WHERE id = :i"),
                                    {"i": plan.network_id}).scalar_one())
        for layer in plan.layers:
            _raster_archive(conn, layer, work / "rasters" / f"{layer.slug}.mbtiles", tick)
        network_tiles = _network_archive(session, plan, version_,
                                         work / "network" / f"{plan.network}.mbtiles", tick)
        say("network as GeoPackage", 0.9)
        segments, nodes = load_network(session, plan.network, plan.bbox)
        write_gpkg(work / "network" / f"{plan.network}.gpkg", segments, nodes)
        say("Lanelet2 map", 0.93)
        heights = ground(conn, plan.elevation_layer) if plan.elevation_layer else None
        lanelet2 = write_lanelet2(read_selection(conn, plan.network, plan.bbox),
                                  work / "lanelet2" / "lanelet2_map.osm", ground=heights)
        manifest = _manifest(plan, version_, len(segments), len(nodes), network_tiles,
                             lanelet2, work)
        (work / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n",
                                            encoding="utf-8")
        say("finishing", 0.98)
        if as_zip:
            _zip(work, out)
            shutil.rmtree(work)
        else:
            if out.exists():
                out.rmdir()
            work.rename(out)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    say("done", 1.0)
    return PackageResult(out, manifest, lanelet2)


def _manifest(plan: PackagePlan, network_version: int, segments: int, nodes: int,
              network_tiles: int, lanelet2: Lanelet2Export, work: Path) -> dict[str, Any]:
    lat, lon = lanelet2.origin
    files = sorted(p for p in work.rglob("*") if p.is_file())
    return {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "created_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "ugvmap_version": version("ugvmap"),
        "bbox": list(plan.bbox),
        "crs": {"bbox": "EPSG:4326", "tiles": "EPSG:3857 (OGC WebMercatorQuad, XYZ)",
                "geopackage": "EPSG:4326",
                "lanelet2": {"projector_type": "LocalCartesianUTM",
                             "map_origin": {"latitude": lat, "longitude": lon, "altitude": 0.0},
                             "utm_zone": lanelet2.utm_zone}},
        "network": {"name": plan.network, "version": network_version, "segments": segments,
                    "nodes": nodes, "clip": "whole segments meeting bbox",
                    "vector_tiles": {"file": f"network/{plan.network}.mbtiles",
                                     "format": "pbf", "tiles": network_tiles,
                                     "minzoom": min((t.z for t in plan.network_tiles),
                                                    default=None),
                                     "maxzoom": max((t.z for t in plan.network_tiles),
                                                    default=None)},
                    "lanelet2": {"file": "lanelet2/lanelet2_map.osm",
                                 "ele": (f"heights of elevation layer {plan.elevation_layer}"
                                         if plan.elevation_layer else "0 (no elevation layer)"),
                                 "projector": f"lanelet2/{PROJECTOR_FILE}",
                                 "lanelets": lanelet2.summary.lanelets,
                                 "movements_not_drawn": len(lanelet2.summary.movements_dropped),
                                 "degenerate_segments": len(lanelet2.summary.defects)}},
        "layers": [{"slug": p.slug, "title": p.title, "version": p.version,
                    "file": f"rasters/{p.slug}.mbtiles", "format": "png", "tile_size": 256,
                    "minzoom": p.minzoom, "maxzoom": p.maxzoom, "bounds": list(p.bounds),
                    "tiles": p.stored} for p in plan.layers],
        "files": [{"path": p.relative_to(work).as_posix(), "bytes": p.stat().st_size,
                   "sha256": _sha256(p)} for p in files],
    }


def _zip(folder: Path, out: Path) -> None:
    """The folder as a zip (tile archives stored, text deflated), written atomically."""
    tmp = out.with_name(f".{out.name}.tmp")
    with zipfile.ZipFile(tmp, "w") as archive:
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            packed = zipfile.ZIP_STORED if path.suffix == ".mbtiles" else zipfile.ZIP_DEFLATED
            archive.write(path, path.relative_to(folder).as_posix(), compress_type=packed)
    tmp.replace(out)
