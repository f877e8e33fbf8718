"""Where an extraction's attribute rules come from: the defaults, the network, the job.

Precedence: the documented defaults (:class:`~app.network.settings.AttributeRules`) < what the
network overrides (``networks.settings["attributes"]``, ``ugvmap network settings``) < what the
job overrides (``ugvmap ingest roads --speed-table ...``, a queued job's ``rules``). Settings
outlive ``--replace`` (they belong to the network, not to its segments).

Rule files: a speed table is CSV ``road_class,speed_kph`` (header row; an empty speed means no
limit) or a JSON object ``{"residential": 30}``; a class table is CSV
``road_class,min_width_m,min_through`` (rows in priority order) or a JSON list of such objects.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

from sqlalchemy import text
from sqlalchemy.orm import Session

from app.network.settings import SETTINGS_KEY, AttributeRules, rules_from
from ingest.network.writer import lock_network
from ingest.roads import RoadsInputError


def _rows(path: Path, columns: tuple[str, ...]) -> Any:
    """A JSON document, or CSV rows as dicts with exactly ``columns`` (empty cells None)."""
    try:
        content = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise RoadsInputError(f"{path}: cannot read the rule table ({exc})") from exc
    if path.suffix.lower() == ".json":
        try:
            return json.loads(content)
        except ValueError as exc:
            raise RoadsInputError(f"{path}: not JSON ({exc})") from exc
    reader = csv.DictReader(content.splitlines())
    if tuple(reader.fieldnames or ()) != columns:
        raise RoadsInputError(f"{path}: a CSV rule table needs the header "
                              f"{','.join(columns)}, not {','.join(reader.fieldnames or ())!r}")
    return [{k: (v.strip() or None) if isinstance(v, str) else v for k, v in row.items()}
            for row in reader]


def read_speed_table(path: Path) -> dict[str, Any]:
    """A speed table file as ``{class: km/h or None}`` (checked with the rules)."""
    rows = _rows(path, ("road_class", "speed_kph"))
    table = rows if isinstance(rows, dict) else {r["road_class"]: r["speed_kph"] for r in rows}
    return rules_from({"speed_kph": table}, str(path)).overrides()["speed_kph"]


def read_class_table(path: Path) -> list[dict[str, Any]]:
    """A class table file as a list of rows (checked with the rules)."""
    rows = _rows(path, ("road_class", "min_width_m", "min_through"))
    if isinstance(rows, list):
        rows = [{k: v for k, v in r.items() if v is not None} if isinstance(r, dict) else r
                for r in rows]
    return rules_from({"classes": rows}, str(path)).overrides()["classes"]


def job_rules(speed_table: Path | None = None, class_table: Path | None = None,
              lane_width: float | None = None,
              junction_length: float | None = None) -> AttributeRules:
    """The overrides of the rule options of ``ingest roads`` / ``network settings``."""
    given: dict[str, Any] = {}
    if speed_table is not None:
        given["speed_kph"] = read_speed_table(speed_table)
    if class_table is not None:
        given["classes"] = read_class_table(class_table)
    if lane_width is not None:
        given["lane_width_m"] = lane_width
    if junction_length is not None:
        given["junction_length_m"] = junction_length
    return rules_from(given, "the rule options")


def network_rules(session: Session, network: str) -> AttributeRules:
    """What network ``network`` overrides (nothing for a network that does not exist yet)."""
    settings = session.execute(text("SELECT settings FROM networks WHERE name = :n"),
                               {"n": network}).scalar()
    return rules_from((settings or {}).get(SETTINGS_KEY, {}),
                      f"the stored settings of network {network!r}")


def effective_rules(session: Session, network: str,
                    job: AttributeRules | None = None) -> AttributeRules:
    """The rules an extraction into ``network`` applies: defaults < network < job."""
    rules = AttributeRules().updated(network_rules(session, network))
    return rules if job is None else rules.updated(job)


def save_network_rules(session: Session, network: str, overrides: AttributeRules,
                       reset: bool = False) -> AttributeRules:
    """Store ``overrides`` on top of the network's (or instead of them with ``reset``), in the
    caller's transaction; a new network is created empty so its rules can be set before its
    first extraction. Returns what the network now overrides."""
    network_id = lock_network(session, network)
    stored = AttributeRules() if reset else network_rules(session, network)
    merged = stored.updated(overrides)
    session.execute(text(
        "UPDATE networks SET settings = jsonb_set(settings, ARRAY[:key], CAST(:rules AS jsonb)) "
        "WHERE id = :id"),
        {"key": SETTINGS_KEY, "rules": json.dumps(merged.overrides()), "id": network_id})
    return merged
