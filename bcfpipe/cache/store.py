"""The content-addressed store of trained materials.

Layout under the cache root (``--cache DIR``, ``BCFPIPE_CACHE``, or the platformdirs user cache)::

  v1/entries/<k[:2]>/<key>/   one trained material: T0..T3.dds, weights.bin, decoder.onnx,
                              material.json, and entry.json (SHA-256 of every file, the
                              measurements of the training run); immutable once written
  v1/locks/<key>.lock         per-key lock (filelock): one process trains a key at a time
  v1/tmp/                     entries being written, and entries being deleted
  v1/facts/<h[:2]>/<h>.json   texel facts of source files, by their XXH3-128 (bcfpipe.cache.facts)
  kernels/                    the compiled training kernels (C++, or numba; bcfpipe.train.fused)

An entry is written into v1/tmp, every file and the folder are fsynced, and the folder is renamed
into place; entry.json is written last, so a folder without a valid entry.json is never an entry.
Every lookup re-hashes the files against entry.json: a damaged entry is moved aside and reported,
never used. The key is the job's content hash (bcfpipe.builder.plan): it covers what changes the
trained files and nothing else.
"""
from __future__ import annotations

import json
import os
import shutil
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from bcfpipe.cache.facts import FactsStore
from bcfpipe.process_env import CACHE_ENV, default_cache_root
from bcfpipe.errors import InputError
from bcfpipe.formats.digest import sha256_file
from bcfpipe.texset.blocks import BlocksStore

LAYOUT = "v1"
ENTRY_META = "entry.json"
ENTRY_FORMAT = "bcfpipe-cache-entry"
ENTRY_VERSION = 1
ENV = CACHE_ENV
default_root = default_cache_root


class CacheError(InputError):
    """The cache folder cannot be used (exit code 2)."""



def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def folder_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


@dataclass(frozen=True)
class Entry:
    """A valid cache entry: its folder, its files with their SHA-256, and what training measured."""

    key: str
    folder: Path
    files: dict[str, str]
    result: dict[str, Any]

    def copy_to(self, dst: str | os.PathLike) -> None:
        """Copy the entry's files (not entry.json) into ``dst``."""
        dst = Path(dst)
        dst.mkdir(parents=True, exist_ok=True)
        for name in self.files:
            shutil.copyfile(self.folder / name, dst / name)


@dataclass(frozen=True)
class EntryInfo:
    key: str
    folder: Path
    size_bytes: int
    created: float
    last_used: float


@dataclass(frozen=True)
class Lookup:
    """What a lookup found: an entry, nothing, or a damaged entry (moved aside; ``problem`` says why)."""

    entry: Entry | None
    problem: str | None = None


class Cache:
    """One cache root. Safe to share between processes and concurrent builds."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root).expanduser().resolve()
        self.base = self.root / LAYOUT
        try:
            for d in ("entries", "locks", "tmp"):
                (self.base / d).mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise CacheError(f"cache folder {self.root}: {e.strerror or e}") from None

        self.facts = FactsStore(self.base)
        self.blocks = BlocksStore(self.base)

    def folder(self, key: str) -> Path:
        if not key or not all(c in "0123456789abcdef" for c in key):
            raise ValueError(f"bad cache key {key!r}")
        return self.base / "entries" / key[:2] / key

    def lock(self, key: str, timeout: float = -1):
        """An exclusive per-key lock (a context manager); blocks until it is free."""
        from filelock import FileLock  # lazy: start-up

        return FileLock(str(self.base / "locks" / f"{key}.lock"), timeout=timeout)

    # ------------------------------------------------------------------------------- read

    def lookup(self, key: str) -> Lookup:
        """The valid entry for ``key``; a damaged one is moved aside and reported."""
        folder = self.folder(key)
        if not folder.is_dir():
            return Lookup(None)
        meta, problem = self._check(folder, key)
        if problem is None:
            try:
                os.utime(folder / ENTRY_META)  # last use, for prune --older-than / --max-size
            except OSError:
                pass
            return Lookup(Entry(key, folder, dict(meta["files"]), dict(meta.get("result") or {})))
        self._discard(folder)
        return Lookup(None, problem)

    def _check(self, folder: Path, key: str) -> tuple[dict, str | None]:
        """entry.json (read once: a concurrent prune may remove the folder) and the problem, if any."""
        try:
            meta = json.loads((folder / ENTRY_META).read_text())
        except FileNotFoundError:
            return {}, "no entry.json"
        except (OSError, ValueError) as e:
            return {}, f"unreadable entry.json ({e})"
        if not isinstance(meta, dict) or meta.get("format") != ENTRY_FORMAT or meta.get("key") != key \
                or not isinstance(meta.get("files"), dict):
            return {}, "entry.json does not describe this entry"
        if meta.get("format_version") != ENTRY_VERSION:
            return {}, f"entry format version {meta.get('format_version')}"
        for name, digest in meta["files"].items():
            path = folder / name
            if "/" in name or not path.is_file():
                return {}, f"{name} is missing"
            try:
                same = sha256_file(path) == digest
            except OSError as e:
                return {}, f"{name} is unreadable ({e.strerror or e})"
            if not same:
                return {}, f"{name} differs from its recorded SHA-256"
        return meta, None

    # ------------------------------------------------------------------------------- write

    def put(self, key: str, src: str | os.PathLike, result: dict[str, Any]) -> Entry:
        """Store the files of folder ``src`` as the entry for ``key`` (atomic; an existing valid
        entry wins). Call with the key's lock held."""
        src = Path(src)
        tmp = self.base / "tmp" / f"{key}.{uuid.uuid4().hex[:8]}"
        tmp.mkdir()
        try:
            files = {}
            for p in sorted(src.iterdir()):
                if p.is_file():
                    shutil.copyfile(p, tmp / p.name)
                    _fsync(tmp / p.name)
                    files[p.name] = sha256_file(tmp / p.name)
            meta = {"format": ENTRY_FORMAT, "format_version": ENTRY_VERSION, "key": key, "files": files,
                    "result": result, "created": time.time()}
            (tmp / ENTRY_META).write_text(json.dumps(meta, indent=2) + "\n")
            _fsync(tmp / ENTRY_META)
            _fsync(tmp)
            final = self.folder(key)
            final.parent.mkdir(parents=True, exist_ok=True)
            if final.exists():
                found = self.lookup(key)
                if found.entry is not None:
                    shutil.rmtree(tmp, ignore_errors=True)
                    return found.entry
            os.rename(tmp, final)
            _fsync(final.parent)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return Entry(key, final, files, result)

    def _discard(self, folder: Path) -> None:
        """Move an entry aside (atomic), then delete it."""
        trash = self.base / "tmp" / f"trash-{folder.name}.{uuid.uuid4().hex[:8]}"
        try:
            os.rename(folder, trash)
        except OSError:
            return
        shutil.rmtree(trash, ignore_errors=True)

    # ------------------------------------------------------------------------------- manage

    def entries(self) -> Iterator[EntryInfo]:
        for shard in sorted((self.base / "entries").iterdir()):
            for folder in sorted(shard.iterdir()) if shard.is_dir() else ():
                meta = folder / ENTRY_META
                try:
                    created = json.loads(meta.read_text()).get("created", 0.0)
                    used = meta.stat().st_mtime
                except (OSError, ValueError):
                    created = used = 0.0
                yield EntryInfo(folder.name, folder, folder_bytes(folder), float(created), used)

    def info(self) -> dict[str, Any]:
        entries = list(self.entries())
        return {"root": str(self.root), "layout": LAYOUT, "entries": len(entries),
                "size_bytes": sum(e.size_bytes for e in entries),
                "leftover_bytes": folder_bytes(self.base / "tmp"), "texel_facts": self.facts.count(),
                "bc_blocks": len(self.blocks.files()), "bc_blocks_bytes": folder_bytes(self.blocks.dir)}

    def prune(self, max_size: int | None = None, older_than: float | None = None,
              now: float | None = None) -> list[EntryInfo]:
        """Delete entries unused for ``older_than`` seconds, then the least recently used until the
        cache holds at most ``max_size`` bytes; also clears leftovers of killed writers, and BC@R's
        blocks unused for ``older_than`` (bcfpipe.texset.blocks; ``max_size`` counts the entries)."""
        now = time.time() if now is None else now
        removed = []
        entries = sorted(self.entries(), key=lambda e: e.last_used)
        keep = []
        for e in entries:
            if older_than is not None and now - e.last_used > older_than:
                removed.append(e)
            else:
                keep.append(e)
        if max_size is not None:
            total = sum(e.size_bytes for e in keep)
            while keep and total > max_size:
                e = keep.pop(0)
                total -= e.size_bytes
                removed.append(e)
        for e in removed:
            with self.lock(e.key):
                self._discard(e.folder)
        if older_than is not None:
            self.blocks.prune(older_than, now)
        self._clear_leftovers(min_age=3600.0, now=now)
        return removed

    def clear(self) -> int:
        """Delete every entry (and the texel facts and BC@R's blocks); returns how many entries."""
        n = 0
        for e in list(self.entries()):
            with self.lock(e.key):
                self._discard(e.folder)
            n += 1
        self._clear_leftovers(min_age=0.0)
        shutil.rmtree(self.facts.dir, ignore_errors=True)
        shutil.rmtree(self.blocks.dir, ignore_errors=True)
        return n

    def _clear_leftovers(self, min_age: float, now: float | None = None) -> None:
        now = time.time() if now is None else now
        for p in (self.base / "tmp").iterdir():
            try:
                if now - p.stat().st_mtime >= min_age:
                    shutil.rmtree(p, ignore_errors=True)
            except OSError:
                pass
