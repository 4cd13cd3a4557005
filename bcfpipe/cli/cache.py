"""`bcfpipe cache`: look at and trim the cache of trained materials (bcfpipe.cache)."""
from __future__ import annotations

import json
import re
import time
from pathlib import Path

import click

from bcfpipe.cache import Cache, default_root
from bcfpipe.cli.errors import Command, Group

_SIZE_UNITS = {"": 1, "B": 1, "K": 1 << 10, "KB": 1 << 10, "KIB": 1 << 10, "M": 1 << 20, "MB": 1 << 20,
               "MIB": 1 << 20, "G": 1 << 30, "GB": 1 << 30, "GIB": 1 << 30, "T": 1 << 40, "TB": 1 << 40,
               "TIB": 1 << 40}
_AGE_UNITS = {"s": 1, "m": 60, "min": 60, "h": 3600, "d": 86400, "w": 7 * 86400}


def parse_size(text: str) -> int:
    """'500M', '2GiB', '1.5G', '123' (bytes; units are powers of 1024)."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([A-Za-z]*)\s*", text)
    if not m or m.group(2).upper() not in _SIZE_UNITS:
        raise click.BadParameter(f"{text!r}: expected a size such as 500M, 2G or 1.5GiB")
    return int(float(m.group(1)) * _SIZE_UNITS[m.group(2).upper()])


def parse_age(text: str) -> float:
    """'30d', '12h', '90m', '2w', '45s' -> seconds."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([A-Za-z]+)\s*", text)
    if not m or m.group(2).lower() not in _AGE_UNITS:
        raise click.BadParameter(f"{text!r}: expected an age such as 30d, 12h, 90m or 2w")
    return float(m.group(1)) * _AGE_UNITS[m.group(2).lower()]


def _fmt_size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


def _open(cache_dir: Path | None):
    return Cache(cache_dir or default_root())


cache_option = click.option("--cache", "cache_dir", type=click.Path(path_type=Path, file_okay=False),
                            help="The cache folder [default: $BCFPIPE_CACHE, else the user cache folder].")
json_option = click.option("--json", "as_json", is_flag=True, help="One JSON object on stdout.")


@click.group("cache", cls=Group)
def cache() -> None:
    """The cache of trained materials that `bcfpipe build` reuses.

    Entries are keyed by the bytes of the source textures and the training options; a build
    takes what it finds and adds what it trains. Deleting entries only costs retraining.
    """


@cache.command("info", cls=Command)
@cache_option
@json_option
def info(cache_dir: Path | None, as_json: bool) -> None:
    """Where the cache is, how many entries it holds and their size."""
    d = _open(cache_dir).info()
    if as_json:
        click.echo(json.dumps(d, indent=2))
        return
    click.echo(f"cache: {d['root']}\nentries: {d['entries']}\nsize: {_fmt_size(d['size_bytes'])}\n"
               f"texel facts: {d['texel_facts']} source file(s) (a rebuild decodes only textures whose bytes changed)\n"
               f"BC@R blocks: {d['bc_blocks']} texture(s), {_fmt_size(d['bc_blocks_bytes'])} (a rebuild with other "
               f"options does not encode BC@R again)")
    if d["leftover_bytes"]:
        click.echo(f"leftovers of interrupted writes: {_fmt_size(d['leftover_bytes'])} (prune removes them)")


@cache.command("list", cls=Command)
@cache_option
@json_option
def list_entries(cache_dir: Path | None, as_json: bool) -> None:
    """Every entry: key, size, when it was made and last used."""
    rows = [{"key": e.key, "size_bytes": e.size_bytes, "created": e.created, "last_used": e.last_used}
            for e in _open(cache_dir).entries()]
    if as_json:
        click.echo(json.dumps(rows, indent=2))
        return
    fmt = "%Y-%m-%d %H:%M"
    for r in rows:
        click.echo(f"{r['key']}  {_fmt_size(r['size_bytes']):>10}  made {time.strftime(fmt, time.localtime(r['created']))}"
                   f"  used {time.strftime(fmt, time.localtime(r['last_used']))}")
    click.echo(f"{len(rows)} entr{'y' if len(rows) == 1 else 'ies'}")


@cache.command("prune", cls=Command)
@cache_option
@click.option("--max-size", metavar="SIZE", help="Keep at most SIZE (e.g. 2G), dropping the least recently used.")
@click.option("--older-than", metavar="AGE", help="Drop entries not used for AGE (e.g. 30d, 12h).")
@json_option
def prune(cache_dir: Path | None, max_size: str | None, older_than: str | None, as_json: bool) -> None:
    """Drop old or least recently used entries (and leftovers of interrupted builds)."""
    if max_size is None and older_than is None:
        raise click.UsageError("give --max-size and/or --older-than")
    size = parse_size(max_size) if max_size is not None else None
    age = parse_age(older_than) if older_than is not None else None
    removed = _open(cache_dir).prune(size, age)
    freed = sum(e.size_bytes for e in removed)
    if as_json:
        click.echo(json.dumps({"removed": [e.key for e in removed], "freed_bytes": freed}, indent=2))
    else:
        click.echo(f"removed {len(removed)} entr{'y' if len(removed) == 1 else 'ies'}, freed {_fmt_size(freed)}")


@cache.command("clear", cls=Command)
@cache_option
@click.option("-y", "--yes", is_flag=True, help="Do not ask.")
def clear(cache_dir: Path | None, yes: bool) -> None:
    """Delete every entry."""
    c = _open(cache_dir)
    if not yes:
        click.confirm(f"delete every entry of {c.root}?", abort=True)
    n = c.clear()
    click.echo(f"removed {n} entr{'y' if n == 1 else 'ies'}")
