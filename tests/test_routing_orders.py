"""Contraction orders are saved, reused and carried across topology edits, and every
hierarchy built from one answers exactly (checked against scipy's Dijkstra on the same arcs).

Pure in-memory graphs (a grid of nodes), no database: this is about the order cache alone.
"""

from __future__ import annotations

import threading

import numpy as np
import pyroutingkit as rk
import pytest
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from app.routing import orders
from app.routing.arcs import Arcs
from app.routing.hierarchy import Hierarchy
from app.settings import get_settings

SIDE = 120  # 14,400 nodes, 28,560 segments: dissection takes a noticeable moment


@pytest.fixture(autouse=True)
def data_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("UGVMAP_DATA_DIR", str(tmp_path))
    get_settings.cache_clear()
    yield tmp_path
    get_settings.cache_clear()


def grid(side: int = SIDE, drop: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, node ids, lon/lat) of a side x side street grid; ``drop`` removes segments."""
    idx = np.arange(side * side).reshape(side, side)
    u = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    v = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    u, v = u[drop:], v[drop:]
    lonlat = np.stack([(idx % side).ravel() * 1e-3, (idx // side).ravel() * 1e-3], axis=1)
    return u, v, np.arange(side * side, dtype=np.int64) * 10 + 7, lonlat


def hierarchy(u, v, ids, lonlat, previous: Hierarchy | None = None) -> Hierarchy:
    return Hierarchy(Arcs.of(u, v, len(ids)), lonlat, ids, previous)


def assert_exact(h: Hierarchy, seed: int) -> None:
    """Distances through the hierarchy equal Dijkstra's on the same arcs and weights."""
    a = h.arcs
    weights = np.random.default_rng(seed).integers(1, 1000, len(a)).astype(np.uint32)
    metric = rk.CCHMetric(h.topology)
    metric.customize(weights)
    matrix = csr_matrix((weights.astype(float), a.head.astype(np.int32), a.indptr),
                        shape=(a.n_nodes, a.n_nodes))
    rng = np.random.default_rng(seed)
    sources = rng.integers(0, a.n_nodes, 5)
    dist = dijkstra(matrix, indices=sources)
    for i, s in enumerate(sources.tolist()):
        for t in rng.integers(0, a.n_nodes, 5).tolist():
            assert metric.query(s, t)[0] == dist[i, t]


def test_order_is_saved_then_loaded() -> None:
    first = hierarchy(*grid())
    first.build()
    assert first.order_source == "dissected"
    again = hierarchy(*grid())  # a restart: same arcs, new objects
    again.build()
    assert again.order_source == "saved"
    np.testing.assert_array_equal(again.order.node_ids, first.order.node_ids)
    assert_exact(again, 1)


def test_concurrent_builds_dissect_once() -> None:
    """Two workers needing the same order: one dissects, the other waits and loads it."""
    pair = [hierarchy(*grid()), hierarchy(*grid())]
    threads = [threading.Thread(target=h.build) for h in pair]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(h.order_source for h in pair) == ["dissected", "saved"]


def test_topology_edit_contracts_in_the_previous_order() -> None:
    """Deleted segments and a new node (a split) reuse the order; routes stay exact."""
    base = hierarchy(*grid())
    base.build()
    u, v, ids, lonlat = grid(drop=40)  # 40 segments deleted
    split = np.array([u[100]]), np.array([v[100]])
    new_id = ids.max() + 1  # a node in the middle of segment 100
    u = np.concatenate([u[:100], u[101:], split[0], [len(ids)]])
    v = np.concatenate([v[:100], v[101:], [len(ids)], split[1]])
    ids = np.append(ids, new_id)
    lonlat = np.vstack([lonlat, lonlat[split[0]] / 2 + lonlat[split[1]] / 2])
    edited = hierarchy(u, v, ids, lonlat, previous=base)
    edited.build()
    assert edited.order_source == "derived" and edited.order.added == 1
    assert edited.order.node_ids[0] == new_id  # contracted first
    assert_exact(edited, 2)


def test_too_many_new_nodes_dissect_again() -> None:
    previous = orders.Order(np.arange(1000, dtype=np.int64), added=5)
    assert orders.derived(previous, np.arange(1005, dtype=np.int64)) is not None  # 10 added
    assert orders.derived(previous, np.arange(1006, dtype=np.int64)) is None  # 11: > 1 %
