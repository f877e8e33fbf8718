"""Job rows as non-admins see them: file names instead of absolute server paths.

A job row's parameters and messages name files on the server (``/srv/data/zone_r0.tif``,
the raster store, a worker's temporary directory). Those reveal the server's layout to
whoever may read ``/jobs``; the file name alone still tells a viewer which input a job is
about, so every absolute path or URI is cut down to its last part.
"""

from __future__ import annotations

import re
from typing import Any

# An absolute POSIX path or a URI (s3://, /vsis3/...). Folder names may hold spaces (a
# "/srv/survey data/zone a.tif" must not leak "survey data"): a folder runs on through single
# spaces up to its "/"; the last part ends at whitespace or a quote. Each space-separated run
# is either inside a folder (a "/" follows) or not, so matching stays linear.
_ABSOLUTE = re.compile(
    r"""(?:\b[a-z][a-z0-9+.-]*://|(?<![\w.~-])/)"""
    r"""(?:[^\s'"<>/]*(?: [^\s'"<>/]+)*/)*[^\s'"<>]*""", re.I)


def _last_part(match: re.Match[str]) -> str:
    path = match.group()
    trail = path[len(path.rstrip(":,;.)]")):]  # punctuation after the path, e.g. "x.tif:"
    return path[: len(path) - len(trail)].rstrip("/").rsplit("/", 1)[-1] + trail


def strip_paths(value: Any) -> Any:
    """``value`` (str, list or dict, nested) with every absolute path replaced by its name."""
    if isinstance(value, str):
        return _ABSOLUTE.sub(_last_part, value)
    if isinstance(value, list):
        return [strip_paths(v) for v in value]
    if isinstance(value, dict):
        return {k: strip_paths(v) for k, v in value.items()}
    return value
