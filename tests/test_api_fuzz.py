"""Schemathesis, a small budget, against the live server's own API document: no operation
(OGC API, editing, vector tiles, raster layers and tiles, routing, jobs, health) may answer
5xx, nor with a status, content type or body the document does not declare.
``bench/api_fuzz.py`` runs the same with a larger budget and the Andorra network."""

from __future__ import annotations

import pytest

from bench.api_fuzz import segment_ids, st_run, write_config
from testkit.network_helpers import grid_network, token

pytestmark = pytest.mark.slow


def test_schemathesis_finds_nothing(live_server: str, tmp_path) -> None:
    network = grid_network().network
    config = write_config(tmp_path / "schemathesis.toml", [network], segment_ids(network),
                          positive_data_acceptance=False)
    result = st_run(live_server, config, token("admin"), max_examples=8, seed=7,
                    timeout_s=300)
    assert result.returncode == 0, result.stdout[-15_000:] + result.stderr[-3_000:]
    assert "Tested:" in result.stdout
