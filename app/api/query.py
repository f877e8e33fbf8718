"""The query-string rule every endpoint shares: each parameter at most once.

A router dependency, so it lives with the HTTP layer; the value rules themselves are the
framework-free parsers of :mod:`app.params`.
"""

from __future__ import annotations

from typing import Any

from fastapi import Depends, Request

from app.errors import InvalidParameterValueError
from app.params import shown


async def single_valued_query(request: Request) -> None:
    """Router dependency: a query parameter given twice is a 400, not silently the last value
    (``revert?to=1&to=2`` would revert to one of them, ``bbox`` twice filter by one). The
    OSRM-shaped routing URLs refuse it themselves, with OSRM's ``InvalidQuery``.

    ``async`` although it awaits nothing: FastAPI runs a plain function dependency in its
    thread pool, and that hop (two thread wake-ups) was most of what a ``/healthz`` cost in
    process (207 -> 100 us) and was paid by every tile and feature request too."""
    seen: set[str] = set()
    for key, _ in request.query_params.multi_items():
        if key in seen:
            raise InvalidParameterValueError(
                f"query parameter {shown(key)} is given more than once; give it once")
        seen.add(key)


def only_query(*names: str) -> Any:
    """Route dependency: a query parameter the endpoint does not take is a 400 naming it,
    as items and routing answer, not silently ignored (a typo such as ``bboxx=`` for a
    Lanelet2 map would hand back the whole network)."""
    takes = ", ".join(names) if names else "no query parameters"

    async def known_query(request: Request) -> None:
        unknown = sorted(set(request.query_params) - set(names))
        if unknown:
            raise InvalidParameterValueError(
                f"unknown query parameter {shown(unknown[0])}; this URL takes {takes}")

    return Depends(known_query)
