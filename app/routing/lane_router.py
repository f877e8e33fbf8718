"""The routing services' GETs reached by one regular expression, ahead of FastAPI's route list.

Why: a city route is planned in well under a millisecond, and FastAPI spent ~0.25 ms reaching
it (measured on Andorra): every request was tried against the ~50 routes listed before the
routing ones (tiles, features, jobs...), then the endpoint's dependencies were solved (path
parameters, the read-access check). :class:`RoutingLane` is the first route of the app: it
takes a GET of either URL family (OSRM's ``/networks/{name}/{service}/v1/{profile}/{coords}``
and ours, ``/networks/{name}/{service}?points=...``) by one regular expression each and calls
the answers the FastAPI endpoints call (:mod:`app.routing.router`), inside the same middleware
and exception handlers; a heavy service (table, match, trip) takes its place in its lane
(:mod:`app.lanes`) first, as the endpoints' dependency does. Those endpoints stay registered:
they document the API and answer whatever the lane leaves to them (reads that need a role,
an app mounted under a root path).
"""

from __future__ import annotations

import re
from typing import Any

from fastapi import FastAPI
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import BaseRoute, Match, NoMatchFound
from starlette.types import Receive, Scope, Send

from app.lanes import lane
from app.routing.options import SERVICES
from app.routing.router import HEAVY_SERVICES, answer_get, answer_osrm
from app.settings import get_settings

_SERVICE = "|".join(SERVICES)
# FastAPI's own path parameters are [^/]+ too: both match the same URLs.
OSRM_URL = re.compile(rf"/networks/(?P<name>[^/]+)/(?P<service>{_SERVICE})/(?P<version>[^/]+)"
                      r"/(?P<profile>[^/]+)/(?P<coordinates>[^/]+)")
OWN_URL = re.compile(rf"/networks/(?P<name>[^/]+)/(?P<service>{_SERVICE})")


class RoutingLane(BaseRoute):
    """A route matching the routing services' GETs (see the module's docstring)."""

    def matches(self, scope: Scope) -> tuple[Match, Scope]:
        """A full match, with the URL's parts as path parameters, for a GET of a routing
        service on public reads; no match for anything else."""
        if (scope["type"] != "http" or scope["method"] != "GET" or scope.get("root_path")
                or get_settings().network_read_role is not None):
            return Match.NONE, {}
        path = scope["path"]
        found = OSRM_URL.fullmatch(path) or OWN_URL.fullmatch(path)
        if found is None:
            return Match.NONE, {}
        return Match.FULL, {"path_params": found.groupdict()}

    async def handle(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Answer as the FastAPI endpoint of the same URL would."""
        part = scope["path_params"]
        kind = HEAVY_SERVICES.get(part["service"])
        if kind is None:
            response = await self._answer(part, Request(scope, receive))
        else:
            async with lane(kind).slot():
                response = await self._answer(part, Request(scope, receive))
        await response(scope, receive, send)

    @staticmethod
    async def _answer(part: dict[str, Any], request: Request) -> Response:
        if "coordinates" in part:
            return await answer_osrm(part["service"], part["name"], request,
                                     part["version"], part["profile"], part["coordinates"])
        return await answer_get(part["service"], part["name"], request)

    def url_path_for(self, name: str, /, **path_params: object) -> None:  # type: ignore[override]
        """Nothing is named after this route: URLs are built from the endpoints' names."""
        raise NoMatchFound(name, path_params)


def install_lane(app: FastAPI) -> None:
    """Put the lane before every other route of ``app``."""
    app.router.routes.insert(0, RoutingLane())
