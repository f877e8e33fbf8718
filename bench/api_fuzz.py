"""Schemathesis over the whole API document: property-based requests against a live server,
checking for 5xx answers and for status codes, content types, headers and bodies the
document does not declare.

    .venv/bin/python bench/api_fuzz.py [--max-examples 30] [--include-path-regex RE]

Creates a throwaway database, imports ``../shared/data/osm/andorra.osm.pbf`` (if present) and a
small grid network, makes an admin token (so edits are exercised, not just refused with 401),
serves it, and runs ``st run`` on ``/openapi.json`` with every phase. Collection ids, network
names and segment ids are drawn from the real data half of the time (a schemathesis
dictionary), so requests reach the logic behind the 404s. ``tests/test_api_fuzz.py`` runs a
small budget of the same over every operation, with a grid network only.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from sqlalchemy import text  # noqa: E402

from app.db.session import session_scope  # noqa: E402
from app.network.tokens import create_token  # noqa: E402
from app.settings import get_settings  # noqa: E402
from testkit.scratch import scratch_database  # noqa: E402
from testkit.server import running_server  # noqa: E402

OSM = REPO.parent / "shared" / "data" / "osm" / "andorra.osm.pbf"
ST = Path(sys.executable).with_name("st")

# Checks left out and why, in the order the reasons apply:
# - positive_data_acceptance: the document cannot say every rule a value must meet (a real
#   calendar date in `datetime`, minlat <= maxlat in `bbox`, a tile inside the grid), and
#   OGC API asks for 400 on such values; the full run reports them (--all-checks).
CONFIG = """
# No crash cache: every run starts from the seed alone, and nothing is written into the repo.
[cache]
enabled = false

[checks.positive_data_acceptance]
enabled = {positive}

# A missing If-Match is 428 Precondition Required (RFC 6585) where the server requires it
# (UGVMAP_IF_MATCH=required; the document marks it optional, the default accepts writes
# without it); an unknown target or method (404, 405) is said first, since RFC 9110
# evaluates preconditions only for a request that could otherwise succeed.
[checks.missing_required_header]
expected-statuses = [400, 401, 403, 404, 405, 406, 415, 422, 428]

# RFC 9110 evaluates If-Match before the body is processed: a stale or garbled ETag is 412
# whatever the body holds.
[checks.negative_data_rejection]
expected-statuses = [400, 401, 403, 404, 405, 406, 409, 412, 415, 422, 428, 429, "5xx"]

[[operations]]
include-path-regex = "/items$"
# A limit above the documented maximum is served as the maximum (the standard's intent, so
# a client asking for "everything" still gets pages), not refused.
checks.negative_data_rejection.enabled = false

[dictionaries.collections]
values = {collections}

[dictionaries.networks]
values = {networks}

[dictionaries.segments]
values = {segments}

[parameters]
"path.collection_id" = {{ dictionary = "collections", probability = 0.5 }}
"path.name" = {{ dictionary = "networks", probability = 0.5 }}
"path.fid" = {{ dictionary = "segments", probability = 0.5 }}
"""


def write_config(path: Path, networks: list[str], segments: list[int], *,
                 positive_data_acceptance: bool) -> Path:
    """A schemathesis.toml drawing ids from the given networks and segments."""
    collections = [f"{n}-{kind}" for n in networks for kind in ("segments", "nodes")]
    path.write_text(CONFIG.format(
        positive=json.dumps(positive_data_acceptance), collections=json.dumps(collections),
        networks=json.dumps(networks), segments=json.dumps([str(s) for s in segments])))
    return path


def segment_ids(network: str, n: int = 20) -> list[int]:
    """A few segment ids of a network, for the ``fid`` dictionary."""
    with session_scope() as session:
        return list(session.execute(text(
            "SELECT s.id FROM road_segments s JOIN networks n ON n.id = s.network_id "
            "WHERE n.name = :n ORDER BY s.id LIMIT :k"), {"n": network, "k": n}).scalars())


def st_run(base: str, config: Path, token: str, *, max_examples: int, seed: int,
           timeout_s: float, filters: tuple[str, ...] = ()) -> subprocess.CompletedProcess[str]:
    """``st run`` against the live server's document, with the admin token on every request.
    """
    return subprocess.run(
        [str(ST), "--config-file", str(config), "--no-color", "run", f"{base}/openapi.json",
         "--max-examples", str(max_examples), "--seed", str(seed), "--workers", "1",
         "--request-timeout", "30", "-H", f"Authorization: Bearer {token}", *filters],
        capture_output=True, text=True, timeout=timeout_s, cwd=config.parent)


def main() -> None:
    """Run schemathesis over every operation and print its report."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-examples", type=int, default=30)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--include-path-regex", default=None)
    ap.add_argument("--all-checks", action="store_true",
                    help="also positive_data_acceptance (schema-valid values refused)")
    args = ap.parse_args()

    from ingest.network import import_network
    from testkit.network_helpers import grid_network

    with scratch_database("ugvmap_fuzz") as url:
        os.environ["DATABASE_URL"] = url
        get_settings.cache_clear()
        networks = [grid_network("grid").network]
        if OSM.is_file():
            with session_scope(url) as session:
                import_network(session, OSM, "andorra")
            networks.append("andorra")
        with session_scope(url) as session:
            token = create_token(session, "fuzz", "admin")
        config = write_config(Path(tempfile.mkdtemp()) / "schemathesis.toml", networks,
                              [s for n in networks for s in segment_ids(n)],
                              positive_data_acceptance=args.all_checks)
        filters = (("--include-path-regex", args.include_path_regex)
                   if args.include_path_regex else ())
        env = {"DATABASE_URL": url, "UGVMAP_LOG_LEVEL": "WARNING"}
        with running_server(env, workers=1) as base:
            result = st_run(base, config, token, max_examples=args.max_examples,
                            seed=args.seed, filters=filters, timeout_s=3600)
        print(result.stdout[-20_000:])
        print(result.stderr[-5_000:], file=sys.stderr)
        sys.exit(result.returncode)


if __name__ == "__main__":
    main()
