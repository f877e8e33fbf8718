"""The road-extraction knobs are one definition (:mod:`app.road_tuning`): the CLI options, the
``ingest-roads`` job's schema and the pipeline's defaults are all derived from it."""

from __future__ import annotations

from typing import Any

import click
import pytest
from click.testing import CliRunner

from app.errors import InvalidValueError
from app.jobs.kinds import RoadsParams, validate_job
from app.road_tuning import DEFAULT_TUNING, RoadTuning, SampleWidth
from cli.main import main
from ingest.roads.pipeline import ExtractParams, tuned_params

COMMANDS = {"extract-roads": RoadTuning.model_fields,
            "ingest roads": {**RoadTuning.model_fields, **SampleWidth.model_fields}}


def command(path: str) -> click.Command:
    found: click.Command = main
    for name in path.split():
        assert isinstance(found, click.Group)
        found = found.commands[name]
    return found


def cli_rule(option: click.Option) -> dict[str, Any]:
    """An option's default and bounds, spelt as in a JSON schema."""
    rule: dict[str, Any] = {"default": option.default}
    if isinstance(option.type, click.Choice):
        rule["enum"] = list(option.type.choices)
    elif isinstance(option.type, click.FloatRange):
        t = option.type
        if t.min is not None:
            rule["exclusiveMinimum" if t.min_open else "minimum"] = t.min
        if t.max is not None:
            rule["exclusiveMaximum" if t.max_open else "maximum"] = t.max
    return rule


def api_rule(schema: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in schema.items()
            if k in ("default", "enum", "minimum", "exclusiveMinimum", "maximum",
                     "exclusiveMaximum")}


@pytest.mark.parametrize("path", COMMANDS)
def test_cli_options_and_job_schema_come_from_one_definition(path: str) -> None:
    options = {p.name: p for p in command(path).params if isinstance(p, click.Option)}
    schema = RoadsParams.model_json_schema()["properties"]
    for name, field in COMMANDS[path].items():
        option = options[name]
        assert option.opts == ["--" + name.replace("_", "-")]
        assert option.help == field.description
        assert cli_rule(option) == api_rule(schema[name]), name
        assert cli_rule(option)["default"] == field.default
        assert len(cli_rule(option)) > 1, f"{name}: neither bounds nor choices"


def test_the_pipeline_defaults_are_the_tuning_defaults() -> None:
    assert tuned_params(DEFAULT_TUNING) == ExtractParams()
    assert tuned_params(RoadTuning(work_resolution=0)).work_resolution_m is None


@pytest.mark.parametrize(("name", "value"), [("k", 0), ("spur_max", 1001), ("simplify", -1),
                                             ("line_width", 0), ("classifier", "magic")])
def test_out_of_range_is_refused_by_both(name: str, value: object) -> None:
    with pytest.raises(InvalidValueError) as refused:
        validate_job("ingest-roads", {"layer": "a", "network": "b", name: value})
    assert list(refused.value.errors) == [f"params.{name}"]
    result = CliRunner().invoke(main, ["ingest", "roads", "--layer", "a", "--network", "b",
                                       "--" + name.replace("_", "-"), str(value)])
    assert result.exit_code == 2 and f"--{name.replace('_', '-')}" in result.output
