"""One hierarchy of user-facing errors, each carrying its documented exit code.

The library raises these; only ``bcfpipe.cli`` turns them into a one-line message and an exit
status (`bcfpipe.cli.errors`). Nothing here depends on click.

Exit codes (every command):
  0  success
  1  the work ran but failed (a material did not build, verification failed, ...)
  2  usage error or unreadable input (bad arguments, missing or corrupt file, refused output)
  130 interrupted (Ctrl-C): running work was cancelled; outputs were left as they were
  143 terminated (SIGTERM, as a build tool or a CI timeout sends it): the same as 130
"""
from __future__ import annotations

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 130, 143


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread (`bcfpipe.cli`), so that it takes Ctrl-C's path: running
    work cancelled, its worker processes stopped, outputs left as they were."""


def raise_terminated(signum, frame) -> None:
    """A SIGTERM handler: `Terminated`."""
    raise Terminated()


class BcfError(Exception):
    """A user-facing error: its message is one line, ``exit_code`` says how the command ends."""

    exit_code = EXIT_USAGE


class InputError(BcfError, ValueError):
    """Bad input or options: a missing or unreadable file, a bad argument, a refused output (2)."""

    exit_code = EXIT_USAGE


class WorkFailed(BcfError):
    """The work ran and failed: a material did not build, a check did not pass (1)."""

    exit_code = EXIT_FAILED


class Unavailable(BcfError, RuntimeError):
    """Something the command needs is not available on this machine, e.g. OpenGL (2)."""

    exit_code = EXIT_USAGE


def one_line(exc: BaseException, limit: int = 300) -> str:
    """``Type: message`` on one line, at most ``limit`` characters (for reports and manifests)."""
    text = " ".join(str(exc).split())
    name = type(exc).__name__
    line = f"{name}: {text}" if text else name
    return line if len(line) <= limit else line[: limit - 3] + "..."
