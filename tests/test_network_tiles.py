"""Vector tiles: decoded content, errors, and an edit visible right after it commits, with the
cache invalidated by NOTIFY (only for tiles the edit touches)."""

from __future__ import annotations

import time

import httpx
import mapbox_vector_tile
import morecantile
import pytest

from testkit.network_helpers import bearer, grid_network
from testkit.server import running_server

TMS = morecantile.tms.get("WebMercatorQuad")


def _tile_url(network: str, lon: float, lat: float, z: int) -> str:
    t = TMS.tile(lon, lat, z)
    return f"/networks/{network}/tiles/{z}/{t.x}/{t.y}.mvt"


def _names(body: bytes) -> set[str]:
    layers = mapbox_vector_tile.decode(body)
    return {f["properties"].get("name") for f in layers.get("segments", {}).get("features", [])}


def _wait_for_hit(get) -> None:
    deadline = time.monotonic() + 5
    while get().headers["x-tile-cache"] != "hit":
        assert time.monotonic() < deadline, "tile never became cached"
        time.sleep(0.05)


@pytest.fixture()
def grid(database_url: str):
    return grid_network()


def test_tile_layers_and_attributes(client, grid) -> None:
    r = client.get(_tile_url(grid.network, 10.001, 50.001, 14))  # the whole grid
    assert r.status_code == 200
    assert r.headers["content-type"] == "application/vnd.mapbox-vector-tile"
    layers = mapbox_vector_tile.decode(r.content)
    segments = layers["segments"]["features"]
    assert len(segments) == 12
    assert {f["properties"]["lanes_forward"] for f in segments} == {2}
    assert {f["properties"]["road_class"] for f in segments} == {"residential"}
    nodes = layers["nodes"]["features"]
    assert len(nodes) == 9 and {f["properties"]["kind"] for f in nodes} >= {"junction"}
    # Below zoom 12 residential streets are not drawn (per-zoom class filter): empty tiles.
    for z in (5, 11):
        low = client.get(_tile_url(grid.network, 10.001, 50.001, z))
        assert low.status_code == 200 and low.content == b""


def test_empty_and_bad_tiles(client, grid) -> None:
    empty = client.get(_tile_url(grid.network, -120.0, -40.0, 14))
    assert empty.status_code == 200 and empty.content == b""
    assert client.get("/networks/nope/tiles/1/0/0.mvt").status_code == 404
    # Addresses outside the grid (404) and malformed ones (400): tests/test_error_model.py.
    for bad, status in (("25/0/0", 404), ("1/2/0", 404), ("1/0/-1", 400), ("a/0/0", 400)):
        assert client.get(f"/networks/{grid.network}/tiles/{bad}.mvt").status_code == status


def test_edit_shows_in_tile_at_once_and_only_touched_tiles_drop(client, grid) -> None:
    here = _tile_url(grid.network, 10.001, 50.001, 14)
    elsewhere_net = grid_network()  # an edit in another network never touches this tile
    get = lambda: client.get(here)  # noqa: E731
    assert "Row 0" in _names(get().content)
    _wait_for_hit(get)

    items = f"/collections/{grid.network}-segments/items"
    fid = client.get(items, params={"limit": 1}).json()["features"][0]["id"]
    r = client.patch(f"{items}/{fid}", json={"name": "Renamed Road"},
                     headers={**bearer("editor"), "If-Match": '"1"'})
    assert r.status_code == 200
    # Right after the commit, before or after the NOTIFY is applied: never the stale tile.
    assert "Renamed Road" in _names(get().content)
    _wait_for_hit(get)
    assert "Renamed Road" in _names(get().content)

    other = f"/collections/{elsewhere_net.network}-segments/items"
    ofid = client.get(other, params={"limit": 1}).json()["features"][0]["id"]
    client.patch(f"{other}/{ofid}", json={"name": "Far away"},
                 headers={**bearer("editor"), "If-Match": '"1"'})
    time.sleep(0.3)
    assert get().headers["x-tile-cache"] == "hit"


def test_tile_bytes_do_not_depend_on_the_rows_physical_order(database_url: str, grid) -> None:
    """A restored database (or any UPDATE, VACUUM FULL) stores rows in another order, and a
    tile must still be the same bytes (the backup round trip compares them): features go into
    the tile ordered by id, whatever order the scan returns them in. A sequential scan returns
    the heap's order; updating the first rows by id moves their new versions behind the rest."""
    from sqlalchemy import text

    from app.db.session import session_scope
    from app.network.tiles import TILE_SQL, zoom_params

    t = TMS.tile(10.001, 50.001, 14)

    def render() -> bytes:
        with session_scope() as session:
            session.execute(text("SET LOCAL enable_indexscan = off; "
                                 "SET LOCAL enable_bitmapscan = off"))
            network_id = session.execute(text("SELECT id FROM networks WHERE name = :n"),
                                         {"n": grid.network}).scalar_one()
            return bytes(session.execute(text(TILE_SQL), {**zoom_params(14), "x": t.x, "y": t.y,
                                                          "network_id": network_id}
                                         ).scalar_one())

    before = render()
    with session_scope() as session:
        for table in ("road_segments", "road_nodes"):
            moved = session.execute(text(
                f"UPDATE {table} t SET id = t.id FROM networks n WHERE n.id = t.network_id AND "
                f"n.name = :n AND t.id IN (SELECT s.id FROM {table} s WHERE s.network_id = n.id "
                "ORDER BY s.id LIMIT 4)"), {"n": grid.network}).rowcount
            assert moved == 4
    after = render()
    assert after == before
    layers = mapbox_vector_tile.decode(after)
    for layer in ("segments", "nodes"):
        ids = [f["id"] for f in layers[layer]["features"]]
        assert len(ids) > 4 and ids == sorted(ids), layer


@pytest.mark.slow
def test_every_worker_sees_the_edit(database_url: str, grid) -> None:
    env = {"DATABASE_URL": database_url}
    with running_server(env, workers=2) as base, httpx.Client(base_url=base) as http:
        tile = _tile_url(grid.network, 10.001, 50.001, 14)
        for _ in range(8):  # warm both workers' caches
            assert "Row 1" in _names(http.get(tile).content)
        items = f"/collections/{grid.network}-segments/items"
        feature = next(f for f in http.get(items, params={"limit": 20}).json()["features"]
                       if f["properties"]["name"] == "Row 1")
        r = http.patch(f"{items}/{feature['id']}", json={"name": "Row One"},
                       headers={**bearer("editor"), "If-Match": '"1"'})
        assert r.status_code == 200
        for _ in range(8):
            segments = mapbox_vector_tile.decode(http.get(tile).content)["segments"]["features"]
            (edited,) = [f for f in segments if f["id"] == feature["id"]]
            assert edited["properties"]["name"] == "Row One"


def test_cache_rules_without_a_server() -> None:
    from app.network.tile_cache import TileCache

    cache = TileCache(max_tiles=2)
    cache.put((1, 0, 0, 0), 5, (0, 0, 1, 1), b"x")
    assert cache.get((1, 0, 0, 0), 5) is None  # not listening yet: nothing is cached
    cache.reset(healthy=True)
    assert cache.get((1, 14, 0, 0), 5) is None  # first sight of network 1 at version 5
    cache.put((1, 14, 0, 0), 5, (0, 0, 1, 1), b"a")
    cache.put((1, 14, 1, 0), 5, (2, 0, 3, 1), b"b")
    assert cache.get((1, 14, 0, 0), 6) is None  # a newer version is not yet applied
    assert cache.invalidate(1, 6, (0.5, 0.5, 0.6, 0.6)) == 1
    assert cache.get((1, 14, 0, 0), 6) is None and cache.get((1, 14, 1, 0), 6) == b"b"
    cache.put((1, 14, 0, 0), 5, (0, 0, 1, 1), b"stale")  # rendered before version 6
    assert cache.get((1, 14, 0, 0), 6) is None
    cache.put((1, 14, 2, 0), 6, (4, 0, 5, 1), b"c")
    cache.put((1, 14, 3, 0), 6, (6, 0, 7, 1), b"d")  # evicts the least recently used
    assert cache.get((1, 14, 1, 0), 6) is None and cache.get((1, 14, 3, 0), 6) == b"d"
    cache.reset(healthy=False)
    assert cache.get((1, 14, 3, 0), 6) is None


def _classes(body: bytes) -> list[str]:
    layers = mapbox_vector_tile.decode(body)
    return [f["properties"]["road_class"] for f in layers.get("segments", {}).get("features", [])]


@pytest.fixture(scope="module")
def country(database_url: str, tmp_path_factory) -> str:
    """The synthetic country network (every class from motorway to service), imported."""
    from app.db.session import session_scope
    from ingest.network import import_network
    from testkit.synthetic_osm import write_country

    pbf = tmp_path_factory.mktemp("tiles") / "country.osm.pbf"
    write_country(pbf, 130, seed=1)  # 15 km square, ~26k segments
    with session_scope() as session:
        return import_network(session, pbf, "tiles-country").network


def test_low_zoom_tiles_filter_classes_and_merge_lines(client, country) -> None:
    centre = (10.11, 50.07)  # the middle of the 130 x 130 x 120 m grid
    full = client.get(_tile_url(country, *centre, 12))
    assert "residential" in _classes(full.content)
    per_segment = _classes(client.get(_tile_url(country, *centre, 10)).content)
    assert len(per_segment) > 100 and "residential" not in per_segment
    assert {"secondary", "tertiary"} <= set(per_segment)
    for z, shown in ((9, {"motorway", "trunk", "primary", "secondary", "tertiary"}),
                     (7, {"motorway", "trunk", "primary"}), (6, {"motorway", "trunk", "primary"})):
        body = client.get(_tile_url(country, *centre, z)).content
        merged = _classes(body)
        # Generalised: one merged line feature per class, and only the classes of the zoom.
        assert sorted(merged) == sorted(shown), z
        props = mapbox_vector_tile.decode(body)["segments"]["features"][0]["properties"]
        assert set(props) == {"road_class", "segments"} and props["segments"] > 1
        assert len(body) < len(full.content)


def test_low_zoom_overview_follows_edits(client, country) -> None:
    """The overview is updated in the edit's transaction: the next z7 tile counts the road."""
    import psycopg

    from app.settings import get_settings
    from tests.routing_support import dsn

    def merged(z: int) -> dict[str, int]:
        body = client.get(_tile_url(country, 10.11, 50.07, z)).content
        return {f["properties"]["road_class"]: f["properties"]["segments"]
                for f in mapbox_vector_tile.decode(body)["segments"]["features"]}

    before = merged(7)
    with psycopg.connect(dsn(get_settings().database_url), autocommit=True) as conn:
        conn.execute("UPDATE road_segments SET road_class = 'primary' WHERE id = (SELECT min(s.id) "
                     "FROM road_segments s JOIN networks n ON n.id = s.network_id "
                     "WHERE n.name = %s AND s.road_class = 'residential')", (country,))
    after = merged(7)
    assert after["primary"] == before["primary"] + 1
    assert after["motorway"] == before["motorway"]
