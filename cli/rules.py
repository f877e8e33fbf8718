"""The attribute-rule options shared by ``ugvmap ingest roads`` (this job) and ``ugvmap network
settings`` (the network's own rules): one definition, so both accept the same files."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

if TYPE_CHECKING:
    from app.network.settings import AttributeRules

RULE_OPTIONS = ("speed_table", "class_table", "lane_width", "junction_length")


def rule_options(command: Callable[..., Any]) -> Callable[..., Any]:
    """Add the rule options (each left out keeps the network's value or the default)."""
    options = [
        click.option("--speed-table", type=click.Path(path_type=Path, dir_okay=False,
                                                      exists=True),
                     help="Default speed per road class: CSV road_class,speed_kph or a JSON "
                          "object (classes not listed keep theirs; empty/null = no limit)."),
        click.option("--class-table", type=click.Path(path_type=Path, dir_okay=False,
                                                      exists=True),
                     help="Road classes: CSV road_class,min_width_m,min_through or a JSON "
                          "list, first matching row wins (replaces the whole table)."),
        click.option("--lane-width", type=float,
                     help="Width of one lane, m (lanes = round(width / lane width)) "
                          "[default: 3.5]."),
        click.option("--junction-length", type=float,
                     help="Longest segment between two junction nodes that counts as part of "
                          "the junction, m [default: 10]."),
    ]
    for option in reversed(options):
        command = option(command)
    return command


def given_rules(options: dict[str, Any]) -> AttributeRules:
    """The overrides the rule options in ``options`` name (files read and checked now)."""
    from ingest.roads.rules import job_rules

    return job_rules(*(options.get(name) for name in RULE_OPTIONS))
