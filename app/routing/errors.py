"""Routing errors, each with the HTTP status and OSRM-style code a client sees."""

from __future__ import annotations


class RoutingError(Exception):
    """A request the router cannot answer; ``code`` follows OSRM where OSRM has one."""

    status = 400
    code = "InvalidQuery"

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class InvalidQueryError(RoutingError):
    """Malformed points or options."""


class TooBigError(RoutingError):
    code = "TooBig"


class NetworkNotFoundError(RoutingError):
    status = 404
    code = "NotFound"


class NoSegmentError(RoutingError):
    """A point is farther than the snap radius from every usable segment."""

    status = 422
    code = "NoSegment"


class NoRouteError(RoutingError):
    """The points are in parts of the network that do not connect (in allowed directions)."""

    status = 422
    code = "NoRoute"


class DatabaseUnavailableError(RoutingError):
    """The graph could not be (re)loaded because the database is unreachable."""

    status = 503
    code = "DatabaseUnavailable"
