"""BC@R's encoded blocks beside the trained materials: each classic texture's BC1/BC4/BC5 blocks at
every level, kept under the XXH3-128 of the encoder and its exact input texels, so that a rebuild
with other options (another preset, profile or layout) does not encode BC@R again. quicktex's BC1
at its top level takes 14 s per 2048² texture with its mips, and holds the GIL.

Layout: ``v1/bc-blocks/<h[:2]>/<h>.npz`` in the cache of the build that made them (``blocks_in``;
none without one: ``--no-cache`` reads and writes nothing here). A file is written to a temporary
name and renamed into place; one that cannot be read is ignored and encoded again, never trusted
half-written. `bcfpipe cache clear` removes them, `prune --older-than` those unused that long.
"""
from __future__ import annotations

import os
import time
import zipfile
from pathlib import Path
from typing import Sequence

import numpy as np

from bcfpipe.formats.atomic import replace_atomically
from bcfpipe.process_env import environment

BLOCKS_ENV = "BCFPIPE_BLOCKS"  # set by a build for itself and its workers: the build cache's bc-blocks/
FORMAT = "bcfpipe-bc-blocks-v1"


class BlocksStore:
    def __init__(self, base: str | os.PathLike):
        self.dir = Path(base) / "bc-blocks"

    def _path(self, key: str) -> Path:
        if not key or not all(c in "0123456789abcdef" for c in key):
            raise ValueError(f"bad blocks key {key!r}")
        return self.dir / key[:2] / f"{key}.npz"

    def get(self, key: str, count: int) -> list[np.ndarray] | None:
        """The ``count`` levels' block arrays recorded under ``key``, or None (absent, unreadable,
        or of another shape)."""
        path = self._path(key)
        try:
            with np.load(path, allow_pickle=False) as z:
                if str(z["format"]) != FORMAT:
                    return None
                levels = [np.ascontiguousarray(z[f"level{k}"], np.uint8) for k in range(count)]
            os.utime(path)  # last use, for prune --older-than
            return levels
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
            return None

    def put(self, key: str, levels: Sequence[np.ndarray]) -> None:
        """Record the levels' blocks; a cache that cannot be written costs an encode next time."""
        def write(tmp: Path) -> None:
            with open(tmp, "wb") as f:  # a file object: savez adds no .npz to the temporary name
                np.savez(f, format=np.array(FORMAT), **{f"level{k}": b for k, b in enumerate(levels)})

        replace_atomically(self._path(key), write)

    def files(self) -> list[Path]:
        return sorted(self.dir.glob("*/*.npz")) if self.dir.is_dir() else []

    def prune(self, older_than: float, now: float | None = None) -> int:
        """Delete the block files unused for ``older_than`` seconds; returns how many."""
        now = time.time() if now is None else now
        n = 0
        for f in self.files():
            try:
                if now - f.stat().st_mtime > older_than:
                    f.unlink()
                    n += 1
            except OSError:
                pass
        return n


def store() -> BlocksStore | None:
    """The store of the build this process works for (``blocks_in``), else None."""
    d = os.environ.get(BLOCKS_ENV)
    return BlocksStore(Path(d).parent) if d else None


def blocks_in(cache_base: str | os.PathLike | None):
    """Within the block (a context manager), this process and the workers it starts keep BC@R's
    blocks under ``cache_base/bc-blocks`` (a build cache's ``v1`` folder); None changes nothing."""
    return environment(BLOCKS_ENV, None if cache_base is None else str(Path(cache_base) / "bc-blocks"))
