"""The faults the core raises, with no HTTP in them (rio-tiler's plain ``errors.py``).

Every fault a caller can cause or must see has one class here, raised wherever it is met:
in the routing engine, a query, a parser or a router. A class says *what* went wrong; how a
client is told (HTTP status, public ``code``, headers) is the edge's business: the HTTP
layer maps each class in one table (:mod:`app.api.errors`, OSRM's URLs in their own), the
command line prints the message. So the batch jobs and the command line raise and catch
these without importing a web framework.

:class:`UserError` is the command line's counterpart: a mistake the user can fix, printed as
one line by the CLI root, raised by ingest code as much as by the commands themselves.
"""

from __future__ import annotations


class UserError(ValueError):
    """A mistake the user can fix (bad file, unknown name, bad option), said in one line.

    A ``ValueError`` so callers that already treat bad values as such keep working; the CLI
    root prints it as ``Error: <message>`` with exit status 1 and no traceback.
    """


class UgvmapError(Exception):
    """Base of every fault a request or command can meet; ``errors`` says, per field, what was
    wrong with it (the editing API's and the value rules' per-field messages)."""

    def __init__(self, message: str, *, errors: dict[str, str] | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.errors = errors


class InvalidParameterValueError(UgvmapError):
    """A malformed query parameter, path part or body (OGC API's code for it)."""


class UnauthorizedError(UgvmapError):
    """No valid token."""


class ForbiddenError(UgvmapError):
    """A valid token whose role may not do this."""


class NotFoundError(UgvmapError):
    """An unknown path, network, collection, feature or job."""


class LayerNotFoundError(NotFoundError):
    """An unknown raster layer: its own code, which clients of the tile API already test for."""


class TileOutOfRangeError(NotFoundError):
    """A well-formed tile address outside the tile-matrix set (zoom > max, x or y >= 2^z)."""


class PreconditionFailedError(UgvmapError):
    """``If-Match`` names a version that is no longer current: someone saved first.
    ``current`` is the version that is, when known, so the answer can say it (as the ``ETag``)."""

    def __init__(self, message: str, *, current: int | None = None) -> None:
        super().__init__(message)
        self.current = current


class ServiceBusyError(UgvmapError):
    """Too many requests of one heavy kind (exports, matches, tables...) at once: refused
    before any work, to be sent again after ``retry_after_s`` (:mod:`app.lanes`)."""

    def __init__(self, message: str, *, retry_after_s: int) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


class InvalidValueError(UgvmapError):
    """Well-formed input whose values break a rule; ``errors`` says which field and why."""

    @classmethod
    def naming(cls, errors: dict[str, str]) -> InvalidValueError:
        """One error naming every field that breaks a rule (its message lists them all), so
        a form can mark them all at once."""
        return cls("; ".join(f"{k}: {v}" for k, v in errors.items()), errors=errors)


class PreconditionRequiredError(UgvmapError):
    """A write without ``If-Match``: refused so edits cannot silently overwrite each other."""


class ConflictError(UgvmapError):
    """A write that met concurrent writes it could not be ordered with (a deadlock or a
    serialization failure) even when tried again: rolled back, nothing changed. Not an
    outage: the database is up, and the same request sent again normally succeeds."""


class StalePreviewError(ConflictError):
    """A road preview made from a version of its layer that was replaced since: accepting it
    would put roads of imagery nobody sees any more into the network (409)."""


class DatabaseUnavailableError(UgvmapError):
    """The database cannot be reached: a fault the client may retry, never a traceback."""


class RasterSourceMissingError(UgvmapError):
    """A tile needs a COG the raster store does not have: the catalogue and the store
    disagree (files deleted, or a process using another store); never a silent blank tile.
    The server log names the file."""


class StoreMismatchError(UgvmapError):
    """``/readyz`` only: this process's raster store is not the one the database's files are
    in (another ``UGVMAP_RASTER_STORE`` or data directory); the server log names both."""


class SchemaOutOfDateError(UgvmapError):
    """The database is reachable but not migrated to the code's head revision."""


# -- routing: named as OSRM names them, since OSRM clients branch on those names -------------
class InvalidQueryError(UgvmapError):
    """Malformed route points or options."""


class TooBigError(UgvmapError):
    """More points than the configured limit."""


class NoSegmentError(UgvmapError):
    """A point is farther than the snap radius from every usable segment."""


class NoRouteError(UgvmapError):
    """The points are in parts of the network that do not connect (in allowed directions)."""


class NoTripsError(UgvmapError):
    """A trip cannot visit every point: some cannot reach each other (OSRM's trip service)."""


class NoMatchError(UgvmapError):
    """No two consecutive points of a trace could be matched to roads (OSRM's match)."""


class InvalidOptionsError(UgvmapError):
    """Route options that parse but do not fit together (one radius per point, ...)."""


class InvalidUrlError(UgvmapError):
    """An OSRM-shaped URL that cannot be read (a bad network name or coordinates part)."""


class InvalidServiceError(UgvmapError):
    """An OSRM service not served here (``tile``, or one OSRM does not have)."""


class InvalidVersionError(UgvmapError):
    """An OSRM protocol version other than ``v1``."""


class NotImplementedOptionError(UgvmapError):
    """A well-formed OSRM option this server does not implement: refused, never ignored."""


class ResponseTooLargeError(UgvmapError):
    """An answer over the configured output caps (coordinates, waypoints): refused before it is
    built, so one request cannot make a worker allocate without bound."""
