"""The options ``ingest roads`` and ``ingest network`` share for ``--update`` (a re-survey
proposed as a change set instead of a replaced network), and the line that reports it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import fields
from typing import Any

import click

from app.errors import UserError
from app.network.resurvey.matching import Tolerances

TOLERANCES = {f.name: f.default for f in fields(Tolerances)}


def _tolerances(ctx: click.Context, param: click.Parameter, values: tuple[str, ...]
                ) -> dict[str, float]:
    out = {}
    for value in values:
        name, _, number = value.partition("=")
        if name not in TOLERANCES:
            raise click.BadParameter(f"{name!r}: not one of {', '.join(TOLERANCES)}")
        try:
            out[name] = float(number)
        except ValueError:
            raise click.BadParameter(f"{value!r}: expected NAME=NUMBER") from None
    try:
        Tolerances(**out)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None
    return out


def update_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """``--update`` and ``--tolerance NAME=VALUE`` (repeatable)."""
    command = click.option(
        "--tolerance", "tolerances", multiple=True, callback=_tolerances, metavar="NAME=VALUE",
        help="With --update: change one matching tolerance (repeatable; defaults: "
             + ", ".join(f"{k}={v:g}" for k, v in TOLERANCES.items()) + ").")(command)
    return click.option(
        "--update", is_flag=True,
        help="Match against the existing network and propose the changes (moved, new, "
             "missing roads) as a change set to review; nothing a person edited is "
             "overwritten (`ugvmap network changes NAME`).")(command)


def check_update(replace: bool, update: bool, tolerances: dict[str, float]) -> None:
    """--update and --replace exclude each other; tolerances need --update."""
    if replace and update:
        raise UserError("--update and --replace exclude each other (update keeps the "
                        "network and proposes changes; replace throws it away)")
    if tolerances and not update:
        raise UserError("--tolerance applies to --update only")


def change_set_line(proposed: dict[str, Any]) -> str:
    """What an update proposed, in one line, and where to review it."""
    counts = ", ".join(f"{n} {kind}" for kind, n in proposed["counts"].items())
    return (f"change set {proposed['id']} for network {proposed['network']} from "
            f"{proposed['source']}: {counts}; review: ugvmap network changes "
            f"{proposed['network']} {proposed['id']}")
