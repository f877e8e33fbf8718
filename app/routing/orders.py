"""Contraction orders of a hierarchy: kept on disk, carried across topology edits.

Nearly all the cost of a CCH topology is the nested-dissection *order* (130 s for a million
segments on a loaded 2-core box); contracting the graph in a given order takes 3-4 s. And a
CCH is exact for *any* order: the order only decides how much fill-in the contraction adds,
hence memory and query speed. So:

- after a topology is built, its order is saved under ``<data dir>/routing/`` keyed by a hash
  of the node ids and arcs (:func:`arcs_digest`), and a later process (a restart, a second
  worker, a new graph version after an undo) with the very same arcs loads it instead of
  dissecting again;
- an edit that changes the arcs (split, merge, segment added or deleted) keeps the previous
  order, by node id, for the nodes that remain, and puts the new nodes first (contracted
  first: a node that splits a road, or a short new road, adds only local shortcuts). Once the
  nodes added this way exceed :data:`DERIVED_SHARE` of the network, the next topology is
  dissected afresh so the order's quality cannot drift.

RoutingKit builds a topology from an order through its own directory format (``tail``,
``head``, ``order``, ``rank``, ``node_count``: raw native uint32 vectors), which is how
``pyroutingkit`` exposes it (:meth:`CCHTopology.load`).
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyroutingkit as rk

from app.routing.arcs import Arcs
from app.settings import get_settings

log = logging.getLogger("ugvmap.routing")

DERIVED_SHARE = 0.01  # new nodes (since the last dissection) beyond which we dissect again
KEPT_FILES = 16  # orders kept on disk, most recently written first


@dataclass(frozen=True)
class Order:
    """A contraction order by node id (first contracted first), and how many of its nodes were
    appended by edits since it was last computed by nested dissection."""

    node_ids: np.ndarray  # int64
    added: int


def arcs_digest(node_ids: np.ndarray, arcs: Arcs) -> str:
    """Hash of the node ids and arcs: equal digests, equal topology input."""
    h = hashlib.blake2b(digest_size=16)
    for a in (node_ids.astype(np.int64), arcs.tail, arcs.head):
        h.update(np.ascontiguousarray(a).data)
    return h.hexdigest()


def _path(digest: str) -> Path:
    return get_settings().data_dir / "routing" / f"cch-order-{digest}.npz"


def saved(digest: str, node_ids: np.ndarray) -> Order | None:
    """The order saved for exactly these arcs, if any."""
    try:
        with np.load(_path(digest)) as f:
            ranks, added = f["order"], int(f["added"])
    except (OSError, ValueError, KeyError):
        return None
    return Order(node_ids[ranks], added) if len(ranks) == len(node_ids) else None


def save(digest: str, order: np.ndarray, added: int) -> None:
    """Keep ``order`` (node indices) for these arcs; best effort (a read-only data directory
    only costs the next process a dissection)."""
    path = _path(digest)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as tmp:
            np.savez(tmp, order=order.astype(np.uint32), added=added)
        os.replace(tmp.name, path)
        older = sorted(path.parent.glob("cch-order-*.npz"), key=lambda p: p.stat().st_mtime)
        for stale in older[:-KEPT_FILES]:
            stale.unlink(missing_ok=True)
            stale.with_suffix(".lock").unlink(missing_ok=True)
    except OSError as exc:
        log.warning("could not save the routing hierarchy's order in %s: %s", path.parent, exc)


@contextmanager
def dissecting(digest: str) -> Iterator[None]:
    """Hold while computing the order of these arcs: another worker process of this data dir
    that needs the same order waits, then loads it instead of dissecting too (best effort)."""
    path = _path(digest).with_suffix(".lock")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = open(path, "w")  # noqa: SIM115 - held across the yield
    except OSError:
        yield
        return
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def derived(previous: Order, node_ids: np.ndarray) -> tuple[np.ndarray, int] | None:
    """(order as node indices, nodes added since the last dissection) for ``node_ids`` from a
    previous order, or ``None`` when too many nodes are new for it to stay a good order."""
    idx = np.searchsorted(node_ids, previous.node_ids)
    hit = idx < len(node_ids)
    hit[hit] = node_ids[idx[hit]] == previous.node_ids[hit]
    kept = idx[hit]
    fresh = np.ones(len(node_ids), bool)
    fresh[kept] = False
    new = np.flatnonzero(fresh)
    added = previous.added + len(new)
    if added > DERIVED_SHARE * len(node_ids):
        return None
    return np.concatenate([new, kept]).astype(np.int64), added


def topology_from(arcs: Arcs, order: np.ndarray) -> rk.CCHTopology:
    """Contract the arcs in ``order`` (node indices, first contracted first): seconds, where
    computing an order takes minutes on a country."""
    n = arcs.n_nodes
    rank = np.empty(n, np.uint32)
    rank[order] = np.arange(n, dtype=np.uint32)
    with tempfile.TemporaryDirectory(prefix="ugvmap-cch-") as d:
        for name, values in (("tail", arcs.tail), ("head", arcs.head),
                             ("order", order), ("rank", rank), ("node_count", [n])):
            np.asarray(values, dtype=np.uint32).tofile(os.path.join(d, name))
        topology = rk.CCHTopology()
        topology.load(d)
    return topology


def order_of(topology: rk.CCHTopology) -> np.ndarray:
    """The contraction order (node indices) of a topology built by nested dissection."""
    with tempfile.TemporaryDirectory(prefix="ugvmap-cch-") as d:
        topology.save(d)
        return np.fromfile(os.path.join(d, "order"), dtype=np.uint32).astype(np.int64)
