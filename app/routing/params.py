"""Strict readers for the raw strings of routing requests: names, numbers, coordinates.

Python's own parsers are too lenient for input from the network: ``float()`` takes ``nan``,
``inf``, ``1_0`` and non-ASCII digits (``٣``), and a NUL byte in a name only fails deep in the
database driver (a 500). The rules are the service-wide ones of :mod:`app.params`; this module
only chooses routing's codes (OSRM's ``InvalidQuery`` for malformed text, 422 ``InvalidValue``
for a well-formed value out of range) and adds the few readers OSRM's options need.
"""

from __future__ import annotations

import re

from app.errors import InvalidQueryError, InvalidValueError
from app.params import parse_float, parse_int, parse_slug

MAX_NUMBER_CHARS = 40  # longer than any float repr; stops multi-megabyte "numbers" early
CONTROL = re.compile("[\x00-\x1f\x7f]")


def point(i: int) -> str:
    """How a message names input point ``i`` (0-based in the code): counted from 1, as people
    count and as the web map numbers its markers."""
    return f"point {i + 1}"


def network_name(name: str) -> str:
    """The network name of a path, or 400 when it cannot name a network (the same pattern the
    ``networks`` table enforces, so a NUL byte or 10 kB name never reaches the database)."""
    return parse_slug(name, "network name")


def bounded(field: str, raw: str, max_chars: int) -> str:
    """``raw`` when it is at most ``max_chars`` long and holds no control character."""
    if len(raw) > max_chars:
        raise InvalidQueryError(f"{field} is {len(raw)} characters long; at most {max_chars}")
    if CONTROL.search(raw):
        raise InvalidQueryError(f"{field} contains a control character")
    return raw


def finite(field: str, raw: str) -> float:
    """A finite number written in plain ASCII decimal, else 400 ``InvalidQuery``."""
    return parse_float(bounded(field, raw.strip(), MAX_NUMBER_CHARS), field,
                       error=InvalidQueryError)


def number_in(field: str, raw: str, lo: float, hi: float, *, open_low: bool = False) -> float:
    """A finite number in ``[lo, hi]`` (``(lo, hi]`` with ``open_low``), else 422
    ``InvalidValue`` naming the range."""
    value = finite(field, raw)
    if not (lo < value if open_low else lo <= value) or value > hi:
        bracket = "(" if open_low else "["
        message = f"{field} must be in {bracket}{lo:g}, {hi:g}], not {value:g}"
        raise InvalidValueError(message, errors={field: message})
    return value


def integer_in(field: str, raw: str, lo: int, hi: int) -> int:
    """A non-negative ASCII integer in ``[lo, hi]``: 400 when malformed, 422 out of range."""
    value = parse_int(bounded(field, raw, MAX_NUMBER_CHARS), field, low=0,
                      error=InvalidQueryError)
    return int(parse_int(value, field, low=lo, high=hi, error=InvalidValueError))


def boolean(field: str, raw: str) -> bool:
    """``true`` or ``false`` (OSRM's spelling; anything else is refused, not guessed)."""
    if raw not in ("true", "false"):
        raise InvalidQueryError(f"{field} must be true or false, not {raw[:40]!r}")
    return raw == "true"


def choice(field: str, raw: str, choices: tuple[str, ...]) -> str:
    """One of ``choices``, else 400 listing them."""
    if raw not in choices:
        raise InvalidQueryError(f"{field} must be one of {', '.join(choices)}, not {raw[:40]!r}")
    return raw


def lonlat(i: int, lon: float, lat: float) -> tuple[float, float]:
    """The point, or 422 naming it when it is outside lon -180..180, lat -90..90."""
    if not (-180 <= lon <= 180 and -90 <= lat <= 90):
        message = f"{point(i)} ({lon:g},{lat:g}) is outside lon -180..180, lat -90..90"
        raise InvalidValueError(message, errors={"points": message})
    return lon, lat
