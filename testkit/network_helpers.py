"""Shared helpers for the network tests and benchmarks: a small synthetic network with known
answers, and API tokens for each role."""

from __future__ import annotations

import uuid
from typing import Any

from app.db.session import session_scope
from app.network.tokens import create_token
from ingest.network import ImportSummary, RoadAttributes, RoadLine, write_network


def grid_network(name: str | None = None, attrs: dict[str, Any] | None = None
                 ) -> ImportSummary:
    """A 3x3 street grid around (10.0, 50.0): 6 straight streets of 2 blocks, noded into
    12 segments that meet at 9 nodes; every segment two lanes each way at 50 km/h, with
    ``attrs`` (e.g. ``{"extracted_from": layer}``, as road extraction writes)."""
    name = name or f"grid-{uuid.uuid4().hex[:8]}"
    step = 0.001
    lines = []
    for i in range(3):
        lines.append(RoadLine([(10.0, 50.0 + i * step), (10.0 + 2 * step, 50.0 + i * step)],
                              RoadAttributes(2, 2, 50.0, road_class="residential",
                                             name=f"Row {i}", attrs=dict(attrs or {}))))
        lines.append(RoadLine([(10.0 + i * step, 50.0), (10.0 + i * step, 50.0 + 2 * step)],
                              RoadAttributes(2, 2, 50.0, road_class="residential",
                                             name=f"Column {i}", attrs=dict(attrs or {}))))
    with session_scope() as session:
        return write_network(session, name, lines)


def token(role: str, name: str | None = None) -> str:
    """A new API token of ``role``."""
    with session_scope() as session:
        return create_token(session, name or f"{role}-{uuid.uuid4().hex[:6]}", role)


def bearer(role: str) -> dict[str, str]:
    """The Authorization header of a new token of ``role``."""
    return {"Authorization": f"Bearer {token(role)}"}
