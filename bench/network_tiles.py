"""Low-zoom vector tiles of a country-size network: per-zoom filtered/generalised vs all rows.

    .venv/bin/python bench/network_tiles.py --network country [--lon 10.55 --lat 50.39]

On a stored network (e.g. the 1M-segment ``country`` from :mod:`testkit.synthetic_osm`,
imported with ``ugvmap ingest network``), renders the tile at (lon, lat) for z6-z12 with the
app's SQL (``app.network.tiles``; the second of two renders, so PostgreSQL's buffers are warm)
and with the per-segment query over every class (what every zoom drew before), and prints
time and size of each with the ratio.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import morecantile
from sqlalchemy import text

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.db.session import session_scope
from app.network import tiles

TMS = morecantile.tms.get("WebMercatorQuad")


def render(session, sql: str, z: int, x: int, y: int, net: int,
           classes: list[str] | None) -> tuple[float, int]:
    """Seconds and bytes of one tile from ``sql`` (second of two runs: warm buffers)."""
    params = {**tiles.zoom_params(z), "x": x, "y": y, "network_id": net,
              "classes": classes}
    for _ in range(2):
        t = time.perf_counter()
        body = bytes(session.execute(text(sql), params).scalar_one())
        took = time.perf_counter() - t
    return took, len(body)


def main() -> None:
    """Render each zoom's tiles both ways and print time and size side by side."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--network", default="country")
    ap.add_argument("--lon", type=float, default=10.55)
    ap.add_argument("--lat", type=float, default=50.39)
    args = ap.parse_args()
    with session_scope() as session:
        net = session.execute(text("SELECT id FROM networks WHERE name = :n"),
                              {"n": args.network}).scalar_one()
        for z in (6, 7, 8, 9, 10, 12):
            t = TMS.tile(args.lon, args.lat, z)
            sql = tiles.OVERVIEW_SQL if z < tiles.MERGE_BELOW else tiles.TILE_SQL
            ours = render(session, sql, z, t.x, t.y, net, tiles.shown_classes(z))
            every = render(session, tiles.TILE_SQL, z, t.x, t.y, net, None)
            print(f"z{z:<2} ugvmap {ours[0] * 1e3:7.0f} ms {ours[1] / 1024:8.1f} KiB | every "
                  f"segment {every[0] * 1e3:7.0f} ms {every[1] / 1024:8.1f} KiB | time ratio "
                  f"{ours[0] / every[0]:.3f}")


if __name__ == "__main__":
    main()
