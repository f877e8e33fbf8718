"""Click options built from pydantic fields, so an option and the job API's field are one
definition (name, type, default, bounds, help).

A field ``work_resolution`` becomes ``--work-resolution``; a ``Literal`` becomes a choice, a
bounded number a :class:`click.FloatRange` with the field's bounds; the field's description
is the help. Used for the road-extraction knobs (:mod:`app.road_tuning`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal, get_args, get_origin

import annotated_types
import click
from pydantic import BaseModel
from pydantic.fields import FieldInfo


def option_name(field: str) -> str:
    """The command-line spelling of a field: ``spur_max`` -> ``--spur-max``."""
    return "--" + field.replace("_", "-")


def _bounded(field: FieldInfo) -> click.FloatRange:
    limits: dict[str, Any] = {}
    for rule in field.metadata:
        if isinstance(rule, annotated_types.Gt):
            limits.update(min=rule.gt, min_open=True)
        elif isinstance(rule, annotated_types.Ge):
            limits.update(min=rule.ge)
        elif isinstance(rule, annotated_types.Lt):
            limits.update(max=rule.lt, max_open=True)
        elif isinstance(rule, annotated_types.Le):
            limits.update(max=rule.le)
    return click.FloatRange(**limits)


def _param_type(field: FieldInfo) -> click.ParamType:
    if get_origin(field.annotation) is Literal:
        return click.Choice([str(v) for v in get_args(field.annotation)])
    if field.annotation is float:
        return _bounded(field)
    raise TypeError(f"no command-line type for a {field.annotation} field")


def field_option(name: str, field: FieldInfo) -> Callable[[Callable[..., Any]], Any]:
    """The ``click.option`` for one field, keeping the field's name as the parameter's."""
    return click.option(option_name(name), name, type=_param_type(field), default=field.default,
                        show_default=True, help=field.description)


def model_options(model: type[BaseModel]) -> Callable[[Callable[..., Any]], Any]:
    """A decorator adding one option per field of ``model``, in the model's order."""
    def decorate(command: Callable[..., Any]) -> Callable[..., Any]:
        for name, field in reversed(model.model_fields.items()):
            command = field_option(name, field)(command)
        return command
    return decorate
