"""Every `bcfpipe …` command line in README.md and docs/ names options the real CLI has (issue 59).

Each line is parsed by the command's own click parser (nothing runs): an unknown option, or an
unknown sub-command, fails with the file and line. Placeholders stay as they are written (`SCENE`,
`--quality Q`): option values are not checked, only that each option exists. Optional parts in
brackets (`[--json]`) are read as written inside them; `…`, `...` and `<...>` are dropped.
"""
from __future__ import annotations

import re
import shlex
from pathlib import Path

import click
import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("**/*.md"))]
# `bcfpipe ...` in backticks, or at the start of a shell line (after an optional "$ ")
INLINE = re.compile(r"`(bcfpipe [^`]*)`")
SHELL = re.compile(r"^\s*(?:\$\s+)?(bcfpipe\s.*)$")


def command_lines() -> list[tuple[str, str]]:
    """(where, the line after "bcfpipe ") for every command line in the docs."""
    found = []
    for path in DOCS:
        fenced = False
        lines = path.read_text().splitlines()
        for n, line in enumerate(lines, 1):
            if line.lstrip().startswith("```"):
                fenced = not fenced
                continue
            hits = [m.group(1) for m in INLINE.finditer(line)]
            if fenced and not hits and (m := SHELL.match(line)):
                text, k = m.group(1), n
                while text.rstrip().endswith("\\") and k < len(lines):  # a continued shell line
                    text = text.rstrip()[:-1] + " " + lines[k].strip()
                    k += 1
                hits = [text.split(" #")[0]]
            for h in hits:
                found += [(f"{path.relative_to(REPO)}:{n}", v) for v in variants(h[len("bcfpipe "):])
                          if not v.split(" ")[0].endswith(":")]  # "bcfpipe build: …" is output, not a command
    return found


def variants(text: str) -> list[str]:
    """A table's ``cache info\\|list\\|prune [--max-size SIZE]``: one line per alternative, each with
    the words before the first."""
    parts = text.split("\\|")
    if len(parts) == 1:
        return [text]
    head = parts[0].rsplit(" ", 1)
    prefix = head[0] + " " if len(head) == 2 else ""
    return [prefix + (head[-1] if i == 0 else p) for i, p in enumerate(parts)]


def tokens(text: str) -> list[str]:
    text = re.sub(r"<[^>]*>", " ", text).replace("…", " ").replace("...", " ").replace("\\", " ")
    text = text.replace("[", " ").replace("]", " ")
    try:
        return shlex.split(text)
    except ValueError:  # an unbalanced quote in prose: split on blanks
        return text.split()


def unknown_options(args: list[str]) -> str | None:
    """Why ``args`` (after "bcfpipe") do not parse, or None."""
    from bcfpipe.cli import main

    cmd: click.Command = main
    ctx = click.Context(main, info_name="bcfpipe")
    while isinstance(cmd, click.Group):
        own = {o for p in cmd.params for o in p.opts + getattr(p, "secondary_opts", [])}
        while args and args[0] in own:  # the group's own flags: "bcfpipe -q build …"
            args = args[1:]
        if not args:
            return None
        if args[0].startswith("-"):
            return f"no option {args[0]!r} before the command"
        sub = cmd.get_command(ctx, args[0])
        if sub is None:
            return f"no command {args[0]!r}"
        cmd, ctx, args = sub, click.Context(sub, info_name=args[0], parent=ctx), args[1:]
    return _parse(cmd, ctx, args)


def _parse(cmd: click.Command, ctx: click.Context, args: list[str]) -> str | None:
    takes_value = {o for p in cmd.params if isinstance(p, click.Option) and not p.is_flag and not p.count
                   for o in p.opts + p.secondary_opts}
    if args and args[-1] in takes_value:  # "`bcfpipe build --jobs`": the option named, its value not
        args = [*args, "X"]
    try:
        cmd.make_parser(ctx).parse_args(args=list(args))
    except click.NoSuchOption as e:
        return e.format_message()
    except click.BadOptionUsage as e:
        return e.format_message()
    return None


LINES = command_lines()


def test_the_docs_hold_command_lines():
    assert len(LINES) > 80, "the pattern no longer finds the docs' command lines"


@pytest.mark.parametrize("where, line", LINES, ids=[w for w, _ in LINES])
def test_every_documented_option_exists(where, line):
    why = unknown_options(tokens(line))
    assert why is None, f"{where}: bcfpipe {line}: {why}"


def test_an_unknown_option_or_command_is_caught():
    """The check can fail: what it would say of lines the docs must not hold."""
    assert "--no-such-option" in unknown_options(tokens("build SCENE --no-such-option"))
    assert "frobnicate" in unknown_options(tokens("frobnicate SCENE"))
    assert "--max-size" in unknown_options(tokens("cache info --max-size 2G"))
    assert unknown_options(tokens("-q build SCENE [--jobs N] --quality Q")) is None
    assert variants("cache info\\|list\\|prune [--max-size SIZE]") == [
        "cache info", "cache list", "cache prune [--max-size SIZE]"]
