"""Atomic file writes: a reader sees the old file or the whole new one, never a partial one."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable


def atomic_write(path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary sibling and a rename (`write_atomically`)."""
    write_atomically(path, lambda tmp: tmp.write_bytes(data))


def write_atomically(path, write: Callable[[Path], None], suffix: str = ".tmp") -> None:
    """``write`` a temporary sibling of ``path`` (named with ``suffix``: a writer that picks its
    format by extension gets one), then rename it into place, so a failure never leaves a partial
    file; the result gets the usual umask-based permissions (mkstemp's are 0600)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def replace_atomically(path: Path, write: Callable[[Path], None]) -> bool:
    """`write_atomically` into ``path``'s folder, made first; False (and nothing left behind) when
    the folder cannot take it. For the cache's derived files, where a failed write only costs
    recomputing them."""
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        write_atomically(path, write)
        return True
    except OSError:
        return False
