"""Raster store on S3 (UGVMAP_RASTER_STORE=s3://bucket/prefix) against a local S3 server over
real HTTP (moto's standalone server, session fixture ``s3_endpoint``): ingest uploads and
registers only complete objects, tiles are read through GDAL's /vsis3/, failures and killed
jobs leave no orphan objects, layer delete removes them."""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from sqlalchemy import text

from app.db.session import get_engine
from app.tiles.store import StoreError, open_store
from cli.main import main
from ingest.raster.cog import write_cog
from ingest.raster.job import ingest_raster
from ingest.raster.sources import Source
from testkit.raster_synth import decode_rgba, synthetic_utm, tiles_around


def _objects(store_uri: str, layer: str) -> list[str]:
    return sorted(open_store(store_uri).refs_under(layer))


def _slug() -> str:
    return f"s3-{uuid.uuid4().hex[:8]}"


def test_ingest_into_and_serve_tiles_from_s3(client, s3_store: str, tmp_path: Path) -> None:
    image, _ = synthetic_utm(tmp_path / "a.tif", width=600, height=500)
    remote, local = _slug(), _slug()
    ingest_raster([image], remote)
    ingest_raster([image], local, store=tmp_path / "local-store")

    stored = _objects(s3_store, remote)
    assert len(stored) == 2 and all(r.startswith(f"{remote}/") for r in stored)
    with get_engine().connect() as conn:
        uris = set(conn.execute(text(
            "SELECT s.uri FROM raster_sources s JOIN layers l ON l.id = s.layer_id "
            "WHERE l.slug = :s UNION SELECT overview_uri FROM layers WHERE slug = :s"),
            {"s": remote}).scalars())
    assert uris == set(stored)  # registered = uploaded, nothing more

    tj = client.get(f"/layers/{remote}/tilejson.json").json()
    w, s, e, n = tj["bounds"]
    # Sources at the native zoom, the layer overview below it.
    for zoom, covered in ((tj["maxzoom"], 0.2), (tj["maxzoom"] - 6, 0.0)):
        x, y, _, _ = tiles_around((w + e) / 2, (s + n) / 2, zoom, n=1)
        from_s3 = client.get(f"/tiles/{remote}/{zoom}/{x}/{y}.png")
        from_disk = client.get(f"/tiles/{local}/{zoom}/{x}/{y}.png")
        assert from_s3.status_code == 200
        pixels = decode_rgba(from_s3.content)
        assert (pixels[..., 3] == 255).mean() > covered
        assert np.array_equal(pixels, decode_rgba(from_disk.content))


def test_large_objects_are_multipart_uploads(s3_store: str, tmp_path: Path) -> None:
    """What ingest does with each finished COG (``store.put``), on a file over the threshold."""
    store = open_store(s3_store)
    local = tmp_path / "big.tif"
    body = np.random.default_rng(1).bytes((9 << 20) + 123)
    local.write_bytes(body)
    store.put(local, "big/cog.tif")
    assert not local.exists()  # consumed
    head = store.client.head_object(Bucket=store.bucket, Key=f"{store.prefix}big/cog.tif")
    assert head["ContentLength"] == len(body)
    assert "-" in head["ETag"]  # S3's mark of a multipart upload: "<md5>-<parts>"
    got = store.client.get_object(Bucket=store.bucket, Key=f"{store.prefix}big/cog.tif")
    assert got["Body"].read() == body


def test_failed_ingest_leaves_no_object_and_registers_nothing(s3_store: str,
                                                              tmp_path: Path) -> None:
    first, _ = synthetic_utm(tmp_path / "1.tif", width=300, height=300)
    second, _ = synthetic_utm(tmp_path / "2.tif", width=300, height=310)  # another file
    calls = []

    def fail_on_second(source: Source, dst: Path) -> None:
        calls.append(source.name)
        if len(calls) == 2:
            raise RuntimeError("disk full")
        write_cog(source.cog_input(), dst, source.dtype, len(source.bands))

    name = _slug()
    with pytest.raises(RuntimeError, match="disk full"):
        ingest_raster([first, second], name, to_cog=fail_on_second)
    assert calls == ["1.tif", "2.tif"]  # the first was uploaded before the failure
    assert _objects(s3_store, name) == []
    with get_engine().connect() as conn:
        assert conn.execute(text("SELECT count(*) FROM layers WHERE slug = :s"),
                            {"s": name}).scalar() == 0


def test_killed_jobs_objects_are_swept_and_delete_removes_the_layer(s3_store: str,
                                                                    tmp_path: Path) -> None:
    name = _slug()
    store = open_store(s3_store)
    orphan = f"{store.prefix}{name}/0123456789abcdef.tif"  # a killed job's finished upload
    store.client.put_object(Bucket=store.bucket, Key=orphan, Body=b"not registered")
    image, _ = synthetic_utm(tmp_path / "a.tif", width=300, height=300)
    ingest_raster([image], name)
    stored = _objects(s3_store, name)
    assert len(stored) == 2 and orphan.removeprefix(store.prefix) not in stored

    result = CliRunner().invoke(main, ["layers", "delete", name, "--yes"])
    assert result.exit_code == 0, result.output
    assert _objects(s3_store, name) == []


def test_store_errors_are_one_line(s3_endpoint: str, database_url: str,
                                   tmp_path: Path) -> None:
    image, _ = synthetic_utm(tmp_path / "a.tif", width=64, height=64)
    with pytest.raises(StoreError, match="expected s3://bucket"):
        open_store("s3://")
    with pytest.raises(StoreError, match="NoSuchBucket"):
        ingest_raster([image], _slug(), store="s3://no-such-bucket-here/x")
