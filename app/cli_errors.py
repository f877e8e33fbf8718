"""The one exception type every ``ugvmap`` command uses for user-facing errors.

A module of its own so capability CLIs can import it at module level without importing
``app.cli`` (which imports them to register their commands).
"""

import click


class CliError(click.ClickException):
    """A user-facing error: printed as one clear line, exit status 1, no traceback."""
