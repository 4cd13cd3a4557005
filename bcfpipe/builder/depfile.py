"""``--depfile``: the files a build's result depends on, in the Makefile syntax gcc's ``-MD``
writes and ninja's ``deps = gcc`` reads (one target; see docs/build.md)."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

from bcfpipe.formats.atomic import atomic_write
from bcfpipe.scan.sources import package_split


def escape(path: str) -> str:
    """A path as a Makefile word: spaces, '#' and '\\' escaped with a backslash, '$' doubled
    (what gcc writes and ninja's depfile parser undoes)."""
    out = []
    for ch in path:
        if ch in " #\\":
            out.append("\\" + ch)
        elif ch == "$":
            out.append("$$")
        elif ch in "\n\r":
            raise ValueError(f"a path with a newline cannot be written to a depfile: {path!r}")
        else:
            out.append(ch)
    return "".join(out)


def _shown(path: str, cwd: Path) -> str:
    """Relative to the working directory when inside it (how build files name their inputs),
    absolute otherwise."""
    p = Path(os.path.abspath(path))
    try:
        return p.relative_to(cwd).as_posix()
    except ValueError:
        return p.as_posix()


def dependencies(layers: Iterable[str], textures: Iterable[str]) -> list[str]:
    """Every composed layer file and every texture read; a packaged file is its package."""
    files = set()
    for f in [*layers, *textures]:
        pkg = package_split(f)
        files.add(pkg[0] if pkg else f)
    return sorted(files)


def render(target: str, deps: Iterable[str], cwd: str | os.PathLike | None = None) -> str:
    cwd = Path(os.path.abspath(cwd or os.getcwd()))
    words = [escape(_shown(d, cwd)) for d in deps]
    return escape(target) + ":" + "".join(f" \\\n  {w}" for w in words) + "\n"


def write(path: str | os.PathLike, target: str, deps: Iterable[str]) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, render(target, deps).encode())
    return path
