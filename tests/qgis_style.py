"""The rules QGIS's MapLibre/Mapbox GL style converter applies to circle layers, re-stated in
Python to read a style the way QGIS (3.28-3.34) does.

Source: qgis/QGIS ``src/core/vectortile/qgsmapboxglstyleconverter.cpp``:

- ``parseLayers()``: one renderer style per layer, with the layer's ``minzoom``/``maxzoom``
  (-1 when absent) and its ``filter`` turned into a QGIS expression by ``parseExpression()``.
- ``parseCircleLayer()``: ``circle-color``/``circle-stroke-color`` as a string is a fixed
  colour; as a list it goes to ``parseValueList()``: ``interpolate`` (by zoom) and ``match``
  are converted, anything else to ``parseExpression()``. ``circle-radius`` as a number is a
  fixed size, a list the same way.
- ``parseExpression()`` knows ``literal``, ``all``/``any``/``none``, ``!``, ``==`` ``!=`` (as
  null-safe ``IS`` / ``IS NOT``), ``<`` ``<=`` ``>`` ``>=``, ``has``/``!has``, ``in``/``!in``,
  ``get``, ``match``, ``to-string``; any other operator (``case``, ``step``, ``coalesce``...)
  is "Skipping unsupported expression": the property is dropped and the symbol keeps QGIS's
  default.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

Props = dict[str, Any]
SUPPORTED = {"literal", "all", "any", "none", "!", "==", "!=", "<", "<=", ">", ">=", "has",
             "!has", "in", "!in", "get", "match", "to-string"}


class UnsupportedError(ValueError):
    """An expression QGIS's converter skips."""


def expression(expr: Any) -> Callable[[Props], Any]:
    """A QGIS-convertible expression as a function of feature properties."""
    if not isinstance(expr, list):
        return lambda props: expr
    op = expr[0]
    if op not in SUPPORTED:
        raise UnsupportedError(op)
    args = [expression(e) for e in expr[1:]] if op not in ("get", "has", "!has", "literal") \
        else []
    if op == "get" or op == "has" or op == "!has":
        name = expr[1]
        if op == "get":
            return lambda props: props.get(name)
        return (lambda props: name in props) if op == "has" else \
            (lambda props: name not in props)
    if op == "literal":
        return lambda props: expr[1]
    if op in ("all", "any", "none"):
        combine = {"all": all, "any": any, "none": lambda xs: not any(xs)}[op]
        return lambda props: combine(a(props) for a in args)
    if op in ("==", "!="):
        equal = op == "=="
        return lambda props: (args[0](props) == args[1](props)) == equal
    if op == "match":
        raise UnsupportedError("match as a filter is not used here")
    compare = {"<": lambda a, b: a < b, "<=": lambda a, b: a <= b, ">": lambda a, b: a > b,
               ">=": lambda a, b: a >= b}.get(op)
    if compare:
        return lambda props: args[0](props) is not None and compare(args[0](props),
                                                                    args[1](props))
    raise UnsupportedError(op)


@dataclass
class CircleStyle:
    """One converted circle layer: where it applies and the fixed values QGIS kept."""

    layer_id: str
    source_layer: str
    min_zoom: int
    max_zoom: int
    applies: Callable[[Props], Any]
    colour: str | None
    radius: float | None
    warnings: list[str] = field(default_factory=list)

    def draws(self, props: Props, zoom: float) -> bool:
        """Whether QGIS draws a feature with ``props`` with this style at ``zoom``."""
        return (self.min_zoom < 0 or zoom >= self.min_zoom) and \
            (self.max_zoom < 0 or zoom <= self.max_zoom) and bool(self.applies(props))


def _value(layer_id: str, value: Any, warnings: list[str]) -> Any:
    if isinstance(value, list):
        if value and value[0] in ("interpolate", "match"):
            return value
        try:
            expression(value)
        except UnsupportedError as exc:
            warnings.append(f"{layer_id}: Skipping unsupported expression ({exc})")
        return None
    return value


def _always(props: Props) -> bool:
    return True


def circle_styles(style: dict[str, Any]) -> list[CircleStyle]:
    """The style's circle layers as QGIS converts them."""
    out = []
    for layer in style["layers"]:
        if layer["type"] != "circle":
            continue
        warnings: list[str] = []
        applies: Callable[[Props], Any] = _always
        try:
            if "filter" in layer:
                applies = expression(layer["filter"])
        except UnsupportedError as exc:
            warnings.append(f"{layer['id']}: unsupported filter ({exc})")
        paint = layer.get("paint", {})
        out.append(CircleStyle(
            layer["id"], layer["source-layer"], int(layer.get("minzoom", -1)),
            int(layer.get("maxzoom", -1)), applies,
            _value(layer["id"], paint.get("circle-color", "#000000"), warnings),
            _value(layer["id"], paint.get("circle-radius", 5), warnings), warnings))
    return out
