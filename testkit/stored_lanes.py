"""Lanes of a segment written straight into the tables, as ``ugvmap ingest lanes`` would
store them: the Lanelet2 tests start from stored paint without rendering a drive."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from sqlalchemy import text

from app.db.session import session_scope

Range = tuple[float, float, int, int, Sequence[float]]
"""(from, to, lanes forward, lanes backward, boundary offsets right to left)."""
Row = tuple[str, str, int | None, float, float, float]
"""(WKT line in EPSG:4326, kind, position, offset, from, to station)."""


def store_lanes(network: str, segment: int, ranges: Sequence[Range], rows: Sequence[Row]
                ) -> None:
    """Insert segment ``segment`` of network ``network``'s lane ranges and boundary rows
    (white paint 0.15 m wide, confidence 0.9)."""
    with session_scope() as session:
        net: int = session.execute(text("SELECT id FROM networks WHERE name = :n"),
                              {"n": network}).scalar_one()
        for lo, hi, f, b, offsets in ranges:
            session.execute(text(
                "INSERT INTO segment_lanes (network_id, segment_id, station_from_m, "
                "station_to_m, lanes_forward, lanes_backward, widths_m, offsets_m) VALUES "
                "(:net, :seg, :lo, :hi, :f, :b, :w, :o)"),
                {"net": net, "seg": segment, "lo": lo, "hi": hi, "f": f, "b": b,
                 "w": np.diff(offsets).tolist(), "o": list(offsets)})
        for wkt, kind, position, offset, lo, hi in rows:
            session.execute(text(
                "INSERT INTO lane_boundaries (network_id, segment_id, geom, kind, colour, "
                "width_m, confidence, position, offset_m, station_from_m, station_to_m) VALUES "
                "(:net, :seg, ST_GeomFromText(:wkt, 4326), :kind, 'white', 0.15, 0.9, :pos, "
                ":off, :lo, :hi)"),
                {"net": net, "seg": segment, "wkt": wkt, "kind": kind, "pos": position,
                 "off": offset, "lo": lo, "hi": hi})
