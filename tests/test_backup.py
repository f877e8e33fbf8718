"""``ugvmap backup`` / ``ugvmap restore``: a round trip into a new, empty database and another
store directory gives the same layers, tile bytes, networks, attributes, edit history and
tokens; a damaged backup or a non-empty target changes nothing; store references are
relative, so the restored server never reads the old store."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import uuid
from pathlib import Path

import httpx
import pytest
from click.testing import CliRunner
from sqlalchemy import create_engine, text

from app.db import migrate
from app.db.session import session_scope
from app.network.tokens import create_token
from app.tiles.store import store_root
from cli.main import main
from cli.ops.backup import COUNTED, MANIFEST
from ingest.raster.job import ingest_raster
from testkit.network_helpers import bearer, grid_network
from testkit.raster_synth import synthetic_utm
from testkit.scratch import scratch_database
from testkit.server import running_server
from tests.conftest import REPO


def _fingerprints(url: str) -> dict[str, str]:
    """One checksum per table over every column of every row, in id order."""
    engine = create_engine(url)
    with engine.connect() as conn:
        out = {t: conn.execute(text(f"SELECT md5(string_agg(t::text, '|' ORDER BY t.id)) "
                                    f"FROM {t} t")).scalar_one() for t in COUNTED}
    engine.dispose()
    return out


def _cli_env(url: str, store: Path) -> dict[str, str]:
    return {**os.environ, "DATABASE_URL": url, "UGVMAP_RASTER_STORE": str(store)}


def _restore(backup: Path, url: str, store: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cli", "restore", str(backup)], cwd=REPO,
                          env=_cli_env(url, store), capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def source(database_url: str, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Data in the session database: a raster layer (two ingests: the overview is replaced),
    a network with attribute edits, a split and a revert in its history, and a token."""
    from fastapi.testclient import TestClient

    from app.main import create_app

    tmp = tmp_path_factory.mktemp("bk-src")
    layer = f"bk-{uuid.uuid4().hex[:8]}"
    first, transform = synthetic_utm(tmp / "a.tif", width=300, height=200)
    second, _ = synthetic_utm(tmp / "b.tif", width=200, height=300,
                              origin=(transform.c + 40, transform.f - 30))
    ingest_raster([first], layer)
    ingest_raster([second], layer)
    net = grid_network()
    with TestClient(create_app()) as client:
        items = f"/collections/{net.network}-segments/items"
        fid = client.get(items).json()["features"][0]["id"]
        editor = bearer("editor")
        for version, name in ((1, "Main St"), (2, "High St")):
            assert client.patch(f"{items}/{fid}", json={"name": name, "speed_limit_kph": 30},
                                headers={**editor, "If-Match": f'"{version}"'}).status_code == 200
        assert client.post(f"{items}/{fid}/revert", params={"to": 2},
                           headers={**editor, "If-Match": '"3"'}).status_code == 200
        assert client.post(f"{items}/{fid}/split", json={"fraction": 0.3},
                           headers={**bearer("admin"), "If-Match": '"4"'}).status_code == 200
        info = client.get(f"/layers/{layer}").json()
        z = info["maxzoom"]
        lon, lat = (info["bounds"][0] + info["bounds"][2]) / 2, \
            (info["bounds"][1] + info["bounds"][3]) / 2
        import morecantile

        tile = morecantile.tms.get("WebMercatorQuad").tile(lon, lat, z)
        urls = [f"/tiles/{layer}/{z}/{tile.x}/{tile.y}.png",
                f"/tiles/{layer}/{z - 1}/{tile.x // 2}/{tile.y // 2}.webp",
                f"/tiles/{layer}/{z - 6}/{tile.x >> 6}/{tile.y >> 6}.png",  # the overview
                f"/networks/{net.network}/tiles/16/34588/22225.mvt"]
        tiles = {u: client.get(u).content for u in urls}
        reads = [f"/layers/{layer}", f"{items}?limit=100", f"{items}/{fid}/history"]
        bodies = {u: client.get(u).json() for u in reads}
    with session_scope() as s:
        create_token(s, "restored-reader", "viewer")
    assert all(len(b) > 100 for u, b in tiles.items() if u.endswith((".png", ".webp")))
    return {"layer": layer, "network": net.network, "tiles": tiles, "bodies": bodies}


def test_round_trip_into_a_new_database_and_store(source, database_url: str,
                                                  tmp_path: Path) -> None:
    backup = tmp_path / "backup"
    result = CliRunner().invoke(main, ["backup", str(backup)])
    assert result.exit_code == 0, result.output
    manifest = json.loads((backup / MANIFEST).read_text())
    files = manifest["store"]["files"]
    assert files and all(not f["path"].startswith("/") for f in files)
    assert any(f["path"].startswith(f"{source['layer']}/overview-") for f in files)
    assert sum(1 for f in files if f["path"].startswith(f"{source['layer']}/")) == 3
    assert manifest["database"]["revision"] == migrate.head_revision()
    before = _fingerprints(database_url)

    new_store = tmp_path / "elsewhere" / "rasters"
    with scratch_database("ugvmap_restore", migrated=False) as new_url:
        proc = _restore(backup, new_url, new_store)
        assert proc.returncode == 0, proc.stderr + proc.stdout
        assert "restored" in proc.stdout
        assert _fingerprints(new_url) == before
        assert (new_store / files[0]["path"]).is_file()
        engine = create_engine(new_url)
        with engine.connect() as conn:  # the backup's own job row was running in the snapshot
            assert conn.execute(text("SELECT status, error FROM ingest_jobs WHERE kind = "
                                     "'backup' ORDER BY id DESC LIMIT 1")).one() == \
                ("failed", "interrupted: restored from a backup taken while it ran")
        engine.dispose()
        # The old store is out of reach: a restored catalogue naming it would fail loudly.
        old = Path(store_root())
        away = old.with_name(old.name + ".away")
        old.rename(away)
        try:
            env = {"DATABASE_URL": new_url, "UGVMAP_RASTER_STORE": str(new_store)}
            with running_server(env) as base:
                for url, body in source["tiles"].items():
                    r = httpx.get(base + url)
                    assert r.status_code == 200 and r.content == body, url
                for url, body in source["bodies"].items():
                    got = httpx.get(base + url).json()
                    got = json.loads(json.dumps(got).replace(base, "http://testserver"))
                    # An items page says when it was answered (OGC timeStamp): not data.
                    got.pop("timeStamp", None)
                    assert got == {k: v for k, v in body.items() if k != "timeStamp"}, url
        finally:
            away.rename(old)
        # A second restore into the now populated database is refused, and changes nothing.
        proc = _restore(backup, new_url, new_store)
        assert proc.returncode == 1 and "not empty" in proc.stderr
        assert _fingerprints(new_url) == before


def test_damaged_backup_and_conflicting_store_are_refused(source, tmp_path: Path) -> None:
    backup = tmp_path / "backup"
    assert CliRunner().invoke(main, ["backup", str(backup)]).exit_code == 0
    assert CliRunner().invoke(main, ["backup", str(backup)]).exit_code == 1  # not empty
    manifest = json.loads((backup / MANIFEST).read_text())
    victim = backup / "rasters" / manifest["store"]["files"][0]["path"]
    data = bytearray(victim.read_bytes())
    data[len(data) // 2] ^= 0xFF
    victim.write_bytes(bytes(data))
    new_store = tmp_path / "store"
    with scratch_database("ugvmap_restore", migrated=False) as new_url:
        proc = _restore(backup, new_url, new_store)
        assert proc.returncode == 1 and "does not match the manifest" in proc.stderr
        assert not new_store.exists()
        engine = create_engine(new_url)
        with engine.connect() as conn:
            assert conn.execute(text("SELECT count(*) FROM pg_tables "
                                     "WHERE schemaname = 'public'")).scalar_one() == 0
        engine.dispose()
        data[len(data) // 2] ^= 0xFF  # repaired; but the store already holds another file
        victim.write_bytes(bytes(data))
        clash = new_store / manifest["store"]["files"][0]["path"]
        clash.parent.mkdir(parents=True)
        clash.write_bytes(b"something else")
        proc = _restore(backup, new_url, new_store)
        assert proc.returncode == 1 and "exists with different content" in proc.stderr
        assert [p.name for p in new_store.rglob("*") if p.is_file()] == [clash.name]
    assert "not a ugvmap backup" in CliRunner().invoke(
        main, ["restore", str(tmp_path)]).output


def test_migration_makes_store_paths_relative(database_url: str) -> None:
    root = store_root()
    with scratch_database("ugvmap_mig", migrated=False) as url:
        from app.db.session import libpq_dsn
        from cli.ops import embedded

        embedded.ensure_database(libpq_dsn(url).rsplit("/", 1)[0] + "/postgres",
                                 url.rsplit("/", 1)[1])
        migrate.upgrade(url, "0006_tokens")
        engine = create_engine(url)
        with engine.begin() as conn:
            layer = conn.execute(text(
                "INSERT INTO layers (slug, title, overview_uri) VALUES ('old', 'old', :o) "
                "RETURNING id"), {"o": f"{root}/old/overview-1.tif"}).scalar_one()
            for uri in (f"{root}/old/a.tif", "/elsewhere/b.tif", "/vsis3/bucket/c.tif"):
                conn.execute(text(
                    "INSERT INTO raster_sources (layer_id, name, uri, footprint, width, height, "
                    "band_count, dtype, resolution_m) VALUES (:l, 'x', :u, "
                    "ST_Multi(ST_MakeEnvelope(0, 0, 1, 1, 3857)), 1, 1, 1, 'uint8', 1)"),
                    {"l": layer, "u": uri})
        migrate.upgrade(url)

        def uris() -> list[str]:
            with engine.connect() as conn:
                return [*conn.execute(text("SELECT overview_uri FROM layers")).scalars(),
                        *conn.execute(text("SELECT uri FROM raster_sources ORDER BY id")
                                      ).scalars()]

        assert uris() == ["old/overview-1.tif", "old/a.tif", "/elsewhere/b.tif",
                          "/vsis3/bucket/c.tif"]
        migrate.downgrade(url, "0006_tokens")
        assert uris() == [f"{root}/old/overview-1.tif", f"{root}/old/a.tif",
                          "/elsewhere/b.tif", "/vsis3/bucket/c.tif"]
        engine.dispose()


def test_file_deletion_waits_for_a_running_backup(database_url: str, tmp_path: Path) -> None:
    """While a backup holds the store lock, ``layers delete`` commits its catalogue change
    but keeps the files until the backup has copied what its snapshot names."""
    import threading

    import psycopg

    from app.db.session import libpq_dsn
    from app.tiles.store import STORE_LOCK

    layer = f"bk-del-{uuid.uuid4().hex[:6]}"
    path, _ = synthetic_utm(tmp_path / "d.tif", width=64, height=64)
    ingest_raster([path], layer)
    files = list((Path(store_root()) / layer).glob("*.tif"))
    assert len(files) == 2
    with psycopg.connect(libpq_dsn(database_url), autocommit=True) as backup:
        backup.execute("SELECT pg_advisory_lock(hashtext(%s))", (STORE_LOCK,))
        deleting = threading.Thread(
            target=lambda: CliRunner().invoke(main, ["layers", "delete", layer, "--yes"]))
        deleting.start()
        deleting.join(2.0)
        assert deleting.is_alive() and all(f.exists() for f in files)
        with session_scope() as s:
            assert s.execute(text("SELECT count(*) FROM layers WHERE slug = :s"),
                             {"s": layer}).scalar_one() == 0
        backup.execute("SELECT pg_advisory_unlock(hashtext(%s))", (STORE_LOCK,))
        deleting.join(30)
    assert not deleting.is_alive() and not any(f.exists() for f in files)
