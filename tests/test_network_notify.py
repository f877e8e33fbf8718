"""Every committed change to a network's segments bumps its version and NOTIFYs listeners."""

from __future__ import annotations

import json
import uuid

import psycopg

from app.db.session import libpq_dsn


def test_segment_change_notifies_with_version_and_bbox(database_url: str) -> None:
    dsn = libpq_dsn(database_url)
    with psycopg.connect(dsn, autocommit=True) as listener, psycopg.connect(dsn) as writer:
        listener.execute("LISTEN network_changed")
        net = writer.execute("INSERT INTO networks (name) VALUES (%s) RETURNING id",
                             (f"n-{uuid.uuid4().hex[:8]}",)).fetchone()[0]
        a, b = (writer.execute(
            "INSERT INTO road_nodes (network_id, geom) VALUES "
            "(%s, ST_SetSRID(ST_MakePoint(%s, 1), 4326)) RETURNING id", (net, x)).fetchone()[0]
            for x in (10.0, 10.002))
        seg = writer.execute(
            "INSERT INTO road_segments (network_id, source_node, target_node, geom, length_m) "
            "VALUES (%s, %s, %s, ST_GeomFromText('LINESTRING(10 1, 10.002 1)', 4326), 222) "
            "RETURNING id", (net, a, b)).fetchone()[0]
        writer.commit()
        ours = [json.loads(n.payload) for n in listener.notifies(timeout=2, stop_after=3)]
        assert {p["network_id"] for p in ours} == {net}
        version_after_insert = max(p["version"] for p in ours)

        writer.execute("UPDATE road_segments SET speed_limit_kph = 30 WHERE id = %s", (seg,))
        # Nothing is announced before commit.
        assert list(listener.notifies(timeout=0.3)) == []
        writer.commit()
        (note,) = list(listener.notifies(timeout=2, stop_after=1))
        payload = json.loads(note.payload)
        assert payload["version"] == version_after_insert + 1
        assert payload["bbox"] == [10.0, 1.0, 10.002, 1.0]
        stored = writer.execute("SELECT version FROM networks WHERE id = %s", (net,)).fetchone()
        assert stored[0] == payload["version"]
