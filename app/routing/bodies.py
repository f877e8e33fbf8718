"""JSON request bodies of the routing services' POST endpoints (long point lists: a trace of
a thousand points, a hundred task points) read into the query string's option strings, so one
parser (:mod:`app.routing.options`) serves both.

A body holds ``points`` (``[[lon, lat], ...]``) and the service's options under the same names
and syntax as the query string; booleans and numbers may also be JSON booleans and numbers,
and a list option a JSON list (``avoid``, ``exclude`` and ``annotations`` joined with commas,
per-point and index lists with semicolons, a bearing as ``[value, range]``, ``null`` for a
point's default). A key the service does not take is refused (422).
"""

from __future__ import annotations

from functools import cache
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, create_model

from app import errors
from app.routing import params
from app.routing.options import Service, option_names

COMMA_LISTS = ("avoid", "exclude", "annotations")
Value = bool | int | float | str | list[Any] | None


class ServiceBody(BaseModel):
    """A POST body: points and options (the fields of each service's model)."""

    model_config = ConfigDict(extra="forbid")

    points: list[Any] = Field(description="[[lon, lat], ...]")

    def raw(self) -> dict[str, str]:
        """The options as the query string would carry them."""
        return {key: _text(key, value) for key, value in
                self.model_dump(exclude={"points"}, exclude_none=True).items()}

    def point_list(self) -> list[tuple[float, float]]:
        """The points; malformed ones are a 400, like the query string's."""
        return [_point(i, p) for i, p in enumerate(self.points)]


def _scalar(key: str, value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float | str):
        return value if isinstance(value, str) else repr(value)
    if isinstance(value, list) and all(isinstance(v, int | float) and not isinstance(v, bool)
                                       for v in value):
        return ",".join(repr(v) for v in value)  # a bearing: [value, range]
    raise errors.InvalidQueryError(f"{key}: {str(value)[:40]} is not a value of this option")


def _text(key: str, value: Any) -> str:
    if isinstance(value, list):
        return ("," if key in COMMA_LISTS else ";").join(_scalar(key, v) for v in value)
    return _scalar(key, value)


def _point(i: int, raw: Any) -> tuple[float, float]:
    """A [lon, lat] pair from the JSON body; malformed input is a 400, like the query string."""
    if not isinstance(raw, list) or len(raw) != 2 or not all(
            isinstance(v, int | float) and not isinstance(v, bool) for v in raw):
        raise errors.InvalidQueryError(f"{params.point(i)} {str(raw)[:60]} is not [lon, lat]")
    lon, lat = (params.finite(params.point(i), repr(v)) for v in raw)
    return params.lonlat(i, lon, lat)


@cache
def body_model(service: Service) -> type[ServiceBody]:
    """The POST body model of a service on our URL family (its OpenAPI schema too)."""
    names = [n for n in option_names(service, "ugvmap") if n != "points"]
    fields: dict[str, Any] = {name: (Value, None) for name in names}
    return create_model(f"{service.title()}Body", __base__=ServiceBody, **fields)
