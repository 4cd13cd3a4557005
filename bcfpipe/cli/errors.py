"""The one place where a library error becomes a one-line message and an exit code.

Every bcfpipe command is a `Command` (or `Group`): a `bcfpipe.errors.BcfError` raised while its
options are parsed or while it runs is printed as ``Error: <message>`` on stderr and ends the
process with the error's ``exit_code`` (0 ok, 1 work failed, 2 usage or input), never a traceback.
Ctrl-C ends it with one line and exit code 130 (the library has already cancelled its workers and
left its outputs as they were); SIGTERM the same way, with exit code 143.
"""
from __future__ import annotations

import click

from bcfpipe.errors import EXIT_INTERRUPTED, EXIT_TERMINATED, BcfError, Terminated


def as_click(exc: BcfError) -> click.ClickException:
    out = click.ClickException(str(exc))
    out.exit_code = exc.exit_code
    return out


class _Reporting:
    def make_context(self, *args, **kwargs):
        try:
            return super().make_context(*args, **kwargs)
        except BcfError as exc:
            raise as_click(exc) from None

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except BcfError as exc:
            raise as_click(exc) from None
        except Terminated:
            click.echo("Error: terminated; running work was cancelled and the output left as it was", err=True)
            ctx.exit(EXIT_TERMINATED)
        except KeyboardInterrupt:
            click.echo("Error: interrupted; running work was cancelled and the output left as it was", err=True)
            ctx.exit(EXIT_INTERRUPTED)


class Command(_Reporting, click.Command):
    """A click command that reports `BcfError` as one line and its exit code."""


class Group(_Reporting, click.Group):
    """A click group whose sub-commands (and itself) report `BcfError` the same way."""

    command_class = Command


Group.group_class = Group
