"""A segment's lane ranges (``segment_lanes``: lanes per direction and their widths, in
stretches along it) read and replaced over the API, at
``/collections/{network}-segments/items/{id}/lanes``.

Why a part of the segment and not a collection of its own: a range has no line or identity
apart from its segment. The ranges cover the segment from end to end and only mean something
together, so the list is replaced whole, and the replacement is one new version of the
segment (its ETag, its ``If-Match``, a history row with the old and new lists under
``lane_ranges``). A revert restores them like any attribute, and ``ugvmap ingest lanes``
keeps the lanes of a segment a person edited. The segment's ``lanes_forward`` /
``lanes_backward`` (what routing and the other exports read) follow the longest range, as
they do after ``ingest lanes``; the Lanelet2 map draws the ranges
(:mod:`app.lanelet2.paint`), its bounds on the segment's painted lines where a boundary
still has them and offset from the segment where it does not.
"""

from __future__ import annotations

import math
from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.errors import InvalidValueError
from app.lanelet2.topology import MAX_LANES, lanes_fit

KEY = "lane_ranges"
"""The pseudo-attribute of a segment's version and history that holds its ranges."""
MAX_RANGES = 64
MAX_LANE_WIDTH_M = 10.0
END_TOLERANCE_M = 1.0
"""How far the last range may end from the segment's length: stations are measured in the
UTM zone's metres (``ingest lanes``), the length on the ellipsoid, 0.04 % apart at most."""
JOIN_TOLERANCE_M = 0.01
FIELDS = ("station_from_m", "station_to_m", "lanes_forward", "lanes_backward", "widths_m",
          "offsets_m")
SERVER_KEPT = ("confidence", "source")
"""Sent back as read: ignored, so a client can PUT what it got after changing a count."""


def read_ranges(session: Session, segment_id: int) -> list[dict[str, Any]]:
    """The segment's ranges in station order, as the API shows them."""
    rows = session.execute(text(
        "SELECT station_from_m, station_to_m, lanes_forward, lanes_backward, widths_m, "
        "offsets_m, confidence, source FROM segment_lanes WHERE segment_id = :s "
        "ORDER BY station_from_m"), {"s": segment_id}).all()
    return [dict(r._mapping) for r in rows]


def _number(value: Any) -> bool:
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value))


def _count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= MAX_LANES


def offsets_of(widths: list[float], forward: int, backward: int) -> list[float]:
    """Boundary offsets right to left (+ left of the segment) for lanes of ``widths`` when
    none are given: the line between the directions on the segment, or a one-way road
    centred on it."""
    start = -sum(widths[:forward]) if forward and backward else -sum(widths) / 2
    out = [start]
    for width in widths:
        out.append(out[-1] + width)
    return [round(v, 3) for v in out]


def _one(i: int, item: Any, errors: dict[str, str]) -> dict[str, Any] | None:
    """One range checked on its own (``errors`` gets what is wrong with it)."""
    where = f"ranges[{i}]"
    if not isinstance(item, dict):
        errors[where] = "must be an object"
        return None
    unknown = sorted(set(item) - set(FIELDS) - set(SERVER_KEPT))
    if unknown:
        errors[where] = (f"unknown member(s) {', '.join(map(str, unknown))[:200]}; allowed: "
                         f"{', '.join(FIELDS)}")
        return None
    bad = [k for k in ("station_from_m", "station_to_m") if not _number(item.get(k))]
    bad += [k for k in ("lanes_forward", "lanes_backward") if not _count(item.get(k))]
    if bad:
        errors[where] = (f"{', '.join(bad)}: stations must be numbers, lane counts whole "
                         f"numbers from 0 to {MAX_LANES}")
        return None
    forward, backward = item["lanes_forward"], item["lanes_backward"]
    n = forward + backward
    widths = item.get("widths_m")
    if (not isinstance(widths, list) or len(widths) != n or n == 0
            or not all(_number(w) and 0 < w <= MAX_LANE_WIDTH_M for w in widths)):
        errors[where] = (f"widths_m must list the width of each of its {n} lanes, right to "
                         f"left, each above 0 and at most {MAX_LANE_WIDTH_M:g} m"
                         + (" (a range needs at least one lane)" if n == 0 else ""))
        return None
    offsets = item.get("offsets_m")
    if offsets is None:
        offsets = offsets_of(widths, forward, backward)
    elif (not isinstance(offsets, list) or len(offsets) != n + 1
          or not all(_number(o) for o in offsets)
          or any(abs((b - a) - w) > 0.05
                 for a, b, w in zip(offsets, offsets[1:], widths, strict=False))):
        errors[where] = (f"offsets_m must list its {n + 1} boundaries right to left (+ left "
                         "of the segment), each lane's width apart (widths_m); or leave it "
                         "out to put the line between the directions on the segment")
        return None
    if not item["station_to_m"] > item["station_from_m"]:
        errors[where] = "station_to_m must be greater than station_from_m"
        return None
    return {"station_from_m": float(item["station_from_m"]),
            "station_to_m": float(item["station_to_m"]), "lanes_forward": forward,
            "lanes_backward": backward, "widths_m": [float(w) for w in widths],
            "offsets_m": [float(o) for o in offsets], "confidence": None, "source": "edited"}


def check_ranges(body: Any, length_m: float, oneway: str) -> list[dict[str, Any]]:
    """The ranges of a PUT body (``{"ranges": [...]}``), checked: each well formed, in order,
    each starting where the one before ends, from 0 to the segment's ``length_m``, and every
    one drivable as the segment's ``oneway`` says (lanes each way it may be driven, none
    against it). An empty list removes them (the segment is mapped as one without paint).
    One 422 names every range that breaks a rule."""
    if not isinstance(body, dict) or set(body) != {"ranges"} \
            or not isinstance(body["ranges"], list):
        raise InvalidValueError('the body must be {"ranges": [...]}: the segment\'s lane '
                                "ranges in station order (an empty list removes them)",
                                errors={"ranges": "required, a list"})
    items = body["ranges"]
    if len(items) > MAX_RANGES:
        raise InvalidValueError(f"at most {MAX_RANGES} ranges per segment",
                                errors={"ranges": f"{len(items)} given"})
    errors: dict[str, str] = {}
    ranges = [_one(i, item, errors) for i, item in enumerate(items)]
    for i, r in enumerate(ranges):
        if r is None:
            continue
        where = f"ranges[{i}]"
        start = 0.0 if i == 0 else (ranges[i - 1] or {}).get("station_to_m")
        if start is not None and abs(r["station_from_m"] - start) > JOIN_TOLERANCE_M:
            errors[where] = (f"station_from_m must be {start:g}: the ranges cover the segment "
                             "end to end, each starting where the one before ends")
        elif i == len(ranges) - 1 and abs(r["station_to_m"] - length_m) > END_TOLERANCE_M:
            errors[where] = (f"station_to_m must be the segment's length, {length_m:.2f} m "
                             f"(within {END_TOLERANCE_M:g} m)")
        elif not lanes_fit(oneway, r["lanes_forward"], r["lanes_backward"]):
            errors[where] = (f"{r['lanes_forward']} lanes forward and {r['lanes_backward']} "
                             f"backward do not fit the segment's oneway {oneway!r} (a lane "
                             "each way it may be driven, none against it)")
    if errors:
        raise InvalidValueError.naming(errors)
    return [r for r in ranges if r is not None]


def store_ranges(session: Session, network_id: int, segment_id: int,
                 ranges: list[dict[str, Any]]) -> None:
    """Replace the segment's rows with ``ranges`` (in the caller's transaction)."""
    session.execute(text("DELETE FROM segment_lanes WHERE segment_id = :s"), {"s": segment_id})
    if ranges:
        session.execute(text(
            "INSERT INTO segment_lanes (network_id, segment_id, station_from_m, station_to_m, "
            "lanes_forward, lanes_backward, widths_m, offsets_m, confidence, source) VALUES "
            "(:net, :seg, :station_from_m, :station_to_m, :lanes_forward, :lanes_backward, "
            ":widths_m, :offsets_m, :confidence, :source)"),
            [{"net": network_id, "seg": segment_id, **r} for r in ranges])


def counts_of(ranges: list[dict[str, Any]]) -> dict[str, int]:
    """The segment's lane counts: those of its longest range (none: no change)."""
    if not ranges:
        return {}
    main = max(ranges, key=lambda r: r["station_to_m"] - r["station_from_m"])
    return {"lanes_forward": main["lanes_forward"], "lanes_backward": main["lanes_backward"]}
