"""Strict readers for the raw strings of routing requests: names, numbers, coordinates.

Python's own parsers are too lenient for input from the network: ``float()`` takes ``nan``,
``inf``, ``1_0`` and non-ASCII digits (``٣``), and a NUL byte in a name only fails deep in the
database driver (a 500). Each reader here either returns a clean value or raises the routing
error that names the field, before anything is searched or allocated.

These overlap the service-wide ``app/params.py`` (name pattern, ASCII numbers, finite floats,
lon/lat ranges) and are meant to be replaced by it once merged; every routing module goes
through this file, so the switch is one import.
"""

from __future__ import annotations

import math
import re

from app.db.models import SLUG_RE
from app.errors import InvalidParameterValueError, InvalidQueryError, InvalidValueError

NAME = re.compile(SLUG_RE)
# A decimal number in ASCII only: no '_' separators, no 'nan'/'inf', no Unicode digits.
NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
INTEGER = re.compile(r"\d+", re.ASCII)
MAX_NUMBER_CHARS = 40  # longer than any float repr; stops multi-megabyte "numbers" early


def network_name(name: str) -> str:
    """The network name of a path, or 400 when it cannot name a network (the same pattern the
    ``networks`` table enforces, so a NUL byte or 10 kB name never reaches the database)."""
    if not NAME.fullmatch(name):
        raise InvalidParameterValueError(
            f"network name {name[:40]!r} must match {SLUG_RE}")
    return name


def bounded(field: str, raw: str, max_chars: int) -> str:
    """``raw`` when it is at most ``max_chars`` long and holds no control character."""
    if len(raw) > max_chars:
        raise InvalidQueryError(f"{field} is {len(raw)} characters long; at most {max_chars}")
    if any(ord(c) < 32 or ord(c) == 127 for c in raw):
        raise InvalidQueryError(f"{field} contains a control character")
    return raw


def finite(field: str, raw: str) -> float:
    """A finite number written in plain ASCII decimal, else 400 ``InvalidQuery``."""
    text = raw.strip()
    if len(text) > MAX_NUMBER_CHARS or not NUMBER.fullmatch(text):
        raise InvalidQueryError(f"{field} {raw[:MAX_NUMBER_CHARS]!r} is not a finite number")
    value = float(text)
    if not math.isfinite(value):  # e.g. 1e999
        raise InvalidQueryError(f"{field} {text!r} is not a finite number")
    return value


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
    if len(raw) > MAX_NUMBER_CHARS or not INTEGER.fullmatch(raw):
        raise InvalidQueryError(f"{field} {raw[:MAX_NUMBER_CHARS]!r} is not an integer")
    value = int(raw)
    if not lo <= value <= hi:
        message = f"{field} must be in [{lo}, {hi}], not {value}"
        raise InvalidValueError(message, errors={field: message})
    return value


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
        message = f"point {i} ({lon:g},{lat:g}) is outside lon -180..180, lat -90..90"
        raise InvalidValueError(message, errors={"points": message})
    return lon, lat
