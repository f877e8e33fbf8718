"""One validation layer for path and query parameters: strict parsers and FastAPI types.

Why one module: hostile input found the same holes in many endpoints (a NUL byte in a name
reaches PostgreSQL, which refuses it with a 500; ``int()`` and ``float()`` accept Unicode
digits like ``٣``; ``float()`` accepts ``nan`` and ``inf``). Each rule is written once here and
every endpoint uses it, so the same fault gives the same 4xx everywhere.

Two layers, both raising a :class:`~app.errors.UgvmapError` (default
:class:`~app.errors.InvalidParameterValueError`, a 400; a caller passes ``error=`` to keep its own
code, e.g. routing's OSRM ``InvalidQuery``):

- ``parse_*``: pure functions from the text a client sent (or a JSON value) to a checked
  Python value, for code that parses by hand (JSON bodies, the CLI; tile addresses keep their
  parser in :func:`app.grid.parse_tile`, with the same ASCII-digits rule, because a well-formed
  address outside the grid is a 404 there, not a 400);
- :class:`Slug`, :class:`Int`, :class:`Finite`, :class:`LonLat`: the same rules as
  ``Annotated`` metadata for FastAPI path and query parameters (``name: NetworkName``,
  ``radius: Annotated[float, Finite("radius", low=0, high=...)] = 50``). The rule runs before
  pydantic's own check, on the raw text; a ``UgvmapError`` is not a ``ValueError``, so pydantic
  lets it through and the app's one handler table answers it. The OpenAPI document still shows
  the parameter's type, pattern and bounds.

Bounds may be callables (``high=lambda: get_settings().x``), read at request time, so a limit
from the environment follows the settings rather than the import.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any

from pydantic import GetCoreSchemaHandler, GetJsonSchemaHandler
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema, core_schema

from app.db.models import SLUG_RE
from app.errors import InvalidParameterValueError, InvalidValueError, UgvmapError

SLUG_PATTERN = SLUG_RE
"""Layer slugs and network names: 1-64 of ``a-z 0-9 _ -``, starting with a letter or digit
(the database's CHECK constraint), so NUL, control characters and ``/`` never get through."""
SLUG_HINT = "1-64 lowercase letters, digits, '-' or '_', starting with a letter or digit"
MAX_TEXT = 40
"""How much of a refused value a message repeats: enough to recognise, never a 50 MB echo."""
INT_RE = re.compile(r"[+-]?[0-9]{1,19}")
MAX_INT = 2**63 - 1
"""No integer parameter exceeds PostgreSQL's bigint, so none reaches the database as an error."""
FLOAT_RE = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]{1,3})?")

Error = type[UgvmapError]
Bound = float | Callable[[], float] | None


def shown(value: object) -> str:
    """``repr`` of a refused value, cut to :data:`MAX_TEXT` characters."""
    text = repr(value)
    return text if len(text) <= MAX_TEXT else text[:MAX_TEXT] + "..."


def _bound(bound: Bound) -> float | None:
    return bound() if callable(bound) else bound


def refuse(error: Error, what: str, reason: str) -> UgvmapError:
    """``error("<what> <reason>")``; a 422 also names the field in ``errors``, as every
    value-rule failure of the API does."""
    errors = {what: reason} if issubclass(error, InvalidValueError) else None
    return error(f"{what} {reason}", errors=errors)


def _check_range(number: float, what: str, low: Bound, high: Bound, error: Error) -> None:
    lo, hi = _bound(low), _bound(high)
    if (lo is not None and number < lo) or (hi is not None and number > hi):
        span = f"{-math.inf if lo is None else lo:g}..{math.inf if hi is None else hi:g}"
        raise refuse(error, what, f"must be within {span}, not {shown(number)}")


def parse_slug(value: str, what: str = "slug", *, error: Error = InvalidParameterValueError
               ) -> str:
    """``value`` if it is a valid slug (:data:`SLUG_PATTERN`), else ``error``."""
    if not isinstance(value, str) or not re.fullmatch(SLUG_PATTERN.strip("^$"), value):
        raise refuse(error, what, f"{shown(value)} is not valid: use {SLUG_HINT}")
    return value


def parse_int(value: str | int, what: str, *, low: Bound = None, high: Bound = None,
              error: Error = InvalidParameterValueError) -> int:
    """An integer written in ASCII digits (``²``, ``٣`` and ``1_000`` are refused, not read
    as numbers), optionally within ``low..high``."""
    if isinstance(value, bool) or not isinstance(value, int | str):
        raise refuse(error, what, "must be an integer")
    if isinstance(value, str):
        if not INT_RE.fullmatch(value):
            raise refuse(error, what, f"must be an integer in ASCII digits, not {shown(value)}")
        value = int(value)
    if abs(value) > MAX_INT:
        raise refuse(error, what, "is too large")
    _check_range(value, what, low, high, error)
    return value


def parse_float(value: str | float, what: str, *, low: Bound = None, high: Bound = None,
                error: Error = InvalidParameterValueError) -> float:
    """A finite number written in ASCII (no ``nan``/``inf``, no Unicode digits), optionally
    within ``low..high``. Also takes a JSON number, where NaN/Infinity may have slipped in."""
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise refuse(error, what, "must be a number")
    if isinstance(value, str) and not FLOAT_RE.fullmatch(value):
        raise refuse(error, what, f"must be a finite decimal number, not {shown(value)}")
    try:
        number = float(value)
    except OverflowError:  # a JSON integer beyond float range
        number = math.inf
    if not math.isfinite(number):
        raise refuse(error, what, f"must be a finite number, not {shown(value)}")
    _check_range(number, what, low, high, error)
    return number


def parse_number(value: Any, what: str, *, low: Bound = None, high: Bound = None,
                 error: Error = InvalidValueError) -> float:
    """A JSON body's number (not a string, not a boolean), finite, optionally bounded."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise refuse(error, what, "must be a number")
    return parse_float(value, what, low=low, high=high, error=error)


def check_lonlat(lon: float, lat: float, what: str = "point", *,
                 error: Error = InvalidParameterValueError) -> tuple[float, float]:
    """Finite lon/lat inside WGS 84's range (lon -180..180, lat -90..90)."""
    if not (math.isfinite(lon) and math.isfinite(lat)):
        raise refuse(error, what, "must be finite numbers")
    if not (-180 <= lon <= 180 and -90 <= lat <= 90):
        raise refuse(error, what, f"({lon:g}, {lat:g}) is outside lon -180..180, lat -90..90")
    return lon, lat


def parse_lonlat(value: str, what: str = "point", *,
                 error: Error = InvalidParameterValueError) -> tuple[float, float]:
    """``"lon,lat"`` -> (lon, lat), finite and in range."""
    parts = value.split(",") if isinstance(value, str) else []
    if len(parts) != 2:
        raise refuse(error, what, f"must be 'lon,lat', not {shown(value)}")
    lon, lat = (parse_float(p.strip(), what, error=error) for p in parts)
    return check_lonlat(lon, lat, what, error=error)


def parse_position(value: Any, what: str = "point", *,
                   error: Error = InvalidValueError) -> tuple[float, float]:
    """A JSON ``[lon, lat]`` (a request body's position) -> (lon, lat), finite and in range."""
    if not (isinstance(value, list) and len(value) == 2):
        raise refuse(error, what, "must be [lon, lat]")
    lon, lat = (parse_number(v, what, error=error) for v in value)
    return check_lonlat(lon, lat, what, error=error)


# -- FastAPI parameter types ------------------------------------------------------------------
class _Rule:
    """Pydantic metadata for ``Annotated[T, Rule(...)]``: parse the raw value with the rule
    before pydantic checks ``T``, and describe the rule in the OpenAPI document."""

    def _parse(self, value: Any) -> Any:
        raise NotImplementedError

    def _extra(self) -> dict[str, Any]:
        return {}

    def __get_pydantic_core_schema__(self, source: Any,
                                     handler: GetCoreSchemaHandler) -> CoreSchema:
        return core_schema.no_info_before_validator_function(self._parse, handler(source))

    def __get_pydantic_json_schema__(self, schema: CoreSchema,
                                     handler: GetJsonSchemaHandler) -> JsonSchemaValue:
        return {**handler(schema), **self._extra()}


@dataclass(frozen=True)
class Slug(_Rule):
    """A slug parameter (layer, network name): ``Annotated[str, Slug("layer slug")]``."""

    what: str
    error: Error = InvalidParameterValueError

    def _parse(self, value: Any) -> str:
        return parse_slug(value, self.what, error=self.error)

    def _extra(self) -> dict[str, Any]:
        return {"pattern": SLUG_PATTERN, "maxLength": 64}


@dataclass(frozen=True)
class _Bounded(_Rule):
    what: str
    low: Bound = None
    high: Bound = None
    error: Error = InvalidParameterValueError

    def _extra(self) -> dict[str, Any]:
        fixed = {"minimum": self.low, "maximum": self.high}
        return {k: v for k, v in fixed.items() if v is not None and not callable(v)}


@dataclass(frozen=True)
class Int(_Bounded):
    """An integer in ASCII digits: ``Annotated[int, Int("to", low=1)]``."""

    def _parse(self, value: Any) -> int:
        return parse_int(value, self.what, low=self.low, high=self.high, error=self.error)


@dataclass(frozen=True)
class Finite(_Bounded):
    """A finite number: ``Annotated[float, Finite("radius", low=0, high=lambda: ...)]``
    (a callable bound is read per request, e.g. from settings)."""

    def _parse(self, value: Any) -> float:
        return parse_float(value, self.what, low=self.low, high=self.high, error=self.error)


@dataclass(frozen=True)
class LonLat(_Rule):
    """``lon,lat`` text -> (lon, lat): ``Annotated[Any, LonLat("point")]`` (typed ``Any``
    because FastAPI would read a tuple-typed query parameter as a repeated one)."""

    what: str
    error: Error = InvalidParameterValueError

    def _parse(self, value: Any) -> tuple[float, float]:
        return parse_lonlat(value, self.what, error=self.error)

    def _extra(self) -> dict[str, Any]:
        return {"type": "string", "pattern": r"^[^,]+,[^,]+$",
                "description": "lon,lat in degrees (WGS 84)"}


class Shape(_Rule):
    """Describe a raw parameter's expected shape in the API document only (``pattern``,
    ``enum``): the endpoint parses the text itself, so a malformed value gets that endpoint's
    own 400/404 rather than pydantic's generic 422, while clients and property-based testers
    read from the document which values make sense."""

    def __init__(self, **schema: Any) -> None:
        self.schema = schema

    def _parse(self, value: Any) -> Any:
        return value

    def _extra(self) -> dict[str, Any]:
        return self.schema


TileZ = Annotated[str, Shape(pattern=r"^[0-9]{1,2}$", description="zoom level")]
TileXY = Annotated[str, Shape(pattern=r"^[0-9]{1,8}$", description="tile column or row")]
LayerSlug = Annotated[str, Slug("layer slug")]
NetworkName = Annotated[str, Slug("network name")]
