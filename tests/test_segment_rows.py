"""``road_segments`` rows are inserted by statements of one module
(:mod:`app.network.segment_rows`), which keeps ``length_m`` the length of ``geom``."""

from __future__ import annotations

import re

import pytest

from app.network.segment_rows import insert_segments
from tests.conftest import REPO

WRITES = re.compile(r"(INSERT\s+INTO|UPDATE)\s+road_segments\b", re.IGNORECASE)


def test_only_segment_rows_spells_a_segment_insert() -> None:
    """(Tests and benchmarks may still poke a row directly, as an outside writer would.)"""
    writers = sorted(str(path.relative_to(REPO))
                     for package in ("app", "ingest", "cli")
                     for path in (REPO / package).rglob("*.py")
                     if WRITES.search(path.read_text()))
    assert writers == ["app/network/segment_rows.py"]


def test_the_length_follows_the_geometry() -> None:
    sql = insert_segments({"network_id": ":n", "geom": "g"}, "t", returning=True)
    assert sql == ("INSERT INTO road_segments (network_id, geom, length_m) "
                   "SELECT :n, g, ST_Length((g)::geography) FROM t RETURNING id")
    for columns in ({"network_id": ":n"}, {"geom": "g", "length_m": "0"}):
        with pytest.raises(ValueError, match="length_m follows"):
            insert_segments(columns)
