"""``bcfpipe ARGS`` run in this process through click's test runner, where a check needs no process
of its own (issue 59): a ``python -m bcfpipe`` subprocess pays about 3 s of torch and USD imports.
Returns what `subprocess.run` would: the exit code, stdout and stderr; an exception the CLI let
through (a bug: the real process would print its traceback) is on stderr as its traceback."""
from __future__ import annotations

import contextlib
import subprocess
import traceback
from pathlib import Path

from click.testing import CliRunner

from bcfpipe.cli import main


def run_cli(*args, cwd: Path | None = None) -> subprocess.CompletedProcess:
    argv = [str(a) for a in args]
    with contextlib.chdir(cwd) if cwd is not None else contextlib.nullcontext():
        r = CliRunner().invoke(main, argv, prog_name="bcfpipe")
    stderr = r.stderr
    if r.exception is not None and not isinstance(r.exception, SystemExit):
        stderr += "Traceback (most recent call last):\n" + "".join(traceback.format_exception(r.exception))
    return subprocess.CompletedProcess(["bcfpipe", *argv], r.exit_code, r.stdout, stderr)
