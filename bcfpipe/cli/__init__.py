"""The `bcfpipe` command line.

Exit codes (all commands):
  0  success
  1  the work ran but failed (a material did not build, verification failed, ...)
  2  usage error or unreadable input (bad arguments, missing or corrupt file)
  130 interrupted (Ctrl-C)
  143 terminated (SIGTERM)
"""
from __future__ import annotations

import logging
import signal
import sys
import threading

import click

from bcfpipe import __version__
from bcfpipe.cli.errors import Group
from bcfpipe.texset import heap
from bcfpipe.errors import EXIT_FAILED, EXIT_OK, EXIT_USAGE, BcfError, raise_terminated  # noqa: F401


class OneFormat(logging.Formatter):
    """Log records as the commands' own lines read: ``bcfpipe: warning: <message>`` (the level in
    lower case), one format for every warning whether logged or printed."""

    def format(self, record: logging.LogRecord) -> str:
        return f"bcfpipe: {record.levelname.lower()}: {record.getMessage()}"


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="bcfpipe")
@click.option("-v", "--verbose", count=True, help="More logging (repeat for debug).")
@click.option("-q", "--quiet", is_flag=True, help="Only errors.")
@click.pass_context
def main(ctx: click.Context, verbose: int, quiet: bool) -> None:
    """Turn the PBR materials of a USD scene into real-time neural materials
    with block-compressed features (Weinreich et al., EG 2024): BC7 by default, or
    the paper's BC6H.

    \b
    Exit codes: 0 ok, 1 work failed, 2 usage error or bad input, 130 interrupted, 143 terminated.
    """
    heap.one_arena()  # before any thread allocates: the fit's threads reuse the heap as it does
    if threading.current_thread() is threading.main_thread():  # SIGTERM stops workers as Ctrl-C does
        before = signal.signal(signal.SIGTERM, raise_terminated)
        ctx.call_on_close(lambda: signal.signal(signal.SIGTERM, before))
    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(OneFormat())
    logging.basicConfig(level=level, handlers=[handler], force=True)  # this run's stderr, run after run
    ctx.ensure_object(dict)
    ctx.obj["quiet"] = quiet


# Sub-commands live next to the code they drive; each module exposes one click command/group.
from bcfpipe.cli.bench import bench  # noqa: E402
from bcfpipe.cli.build import build  # noqa: E402
from bcfpipe.cli.cache import cache  # noqa: E402
from bcfpipe.cli.dds import dds  # noqa: E402
from bcfpipe.cli.decode import decode  # noqa: E402
from bcfpipe.cli.plan import plan_cmd  # noqa: E402
from bcfpipe.cli.render import render  # noqa: E402
from bcfpipe.cli.scan import scan  # noqa: E402
from bcfpipe.cli.shaders import shaders  # noqa: E402
from bcfpipe.cli.train import train_cmd  # noqa: E402
from bcfpipe.cli.verify import verify  # noqa: E402

for _cmd in (bench, build, cache, decode, dds, plan_cmd, render, scan, shaders, train_cmd, verify):
    main.add_command(_cmd)
