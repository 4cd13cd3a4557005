"""User-facing errors and the documented exit codes shared by every command."""
from __future__ import annotations

import click

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


class BcfError(click.ClickException):
    """A user-facing error: printed as one line, exit code 2."""

    exit_code = EXIT_USAGE
