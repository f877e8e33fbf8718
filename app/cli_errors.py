"""The one exception type every ``ugvmap`` command uses for user-facing errors.

A module of its own so capability CLIs can import it at module level without importing
``app.cli`` (which imports them to register their commands).
"""

import click


class CliError(click.ClickException):
    """A user-facing error: printed as one clear line, exit status 1, no traceback."""


class UgvmapGroup(click.Group):
    """The root command group: a database that cannot be reached, from any command, is one
    clear line instead of a traceback (so no command has to catch it itself)."""

    def invoke(self, ctx: click.Context) -> object:
        from sqlalchemy.exc import OperationalError

        try:
            return super().invoke(ctx)
        except OperationalError as exc:
            raise CliError(
                f"cannot reach the database ({exc.orig}); `ugvmap db start`?") from exc
