"""What bcfpipe reads from and sets in the process environment: the cache root (``BCFPIPE_CACHE``),
the folder compiled kernels live in (`kernels_dir`, `kernel_cache`), and variables set for a block
(how a build points its workers at its cache's folders)."""
from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

CACHE_ENV = "BCFPIPE_CACHE"
KERNELS_ENV = "BCFPIPE_KERNELS"  # set by a build for its workers: the kernels of the build's cache


def default_cache_root() -> Path:
    """The cache folder when none is given: ``BCFPIPE_CACHE``, else the platformdirs user cache
    folder of bcfpipe. Trained materials live there (bcfpipe.cache), and compiled kernels under
    ``kernels/`` (`kernels_dir`)."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    import platformdirs  # lazy: start-up

    return Path(platformdirs.user_cache_dir("bcfpipe", appauthor=False))


def kernels_dir() -> str:
    """Compiled kernels (the fused training step's, the BC decoders') live in bcfpipe's cache
    (``kernels/``): the build's (``--cache``), else the default one; never beside the package or in
    numba's default places. NUMBA_CACHE_DIR, when set, wins."""
    return (os.environ.get("NUMBA_CACHE_DIR") or os.environ.get(KERNELS_ENV)
            or str(default_cache_root() / "kernels"))


def kernel_cache() -> bool:
    """Point numba's cache at `kernels_dir` (before any decorator reads it) and say whether compiled
    kernels can be kept there (the folder exists or can be made, and takes a file). Modules of numba
    kernels call it before they import numba's decorators and decorate with ``cache=`` its answer:
    where the folder cannot be written they compile in each process, since numba would otherwise
    fall back to writing beside the package."""
    import numba.core.config  # lazy: start-up

    folder = kernels_dir()
    numba.core.config.CACHE_DIR = folder
    try:
        os.makedirs(folder, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".probe-"):
            pass
    except OSError:
        return False
    return True


def without_cache(call, namespace: dict):
    """``call()``; if numba cannot write a kernel's cache (a full cache folder), every kernel in
    ``namespace`` (a module's globals) compiles without one and ``call`` runs again: a slower start,
    never a failure."""
    try:
        return call()
    except OSError:
        from numba.core.caching import NullCache  # lazy: start-up
        from numba.core.registry import CPUDispatcher  # lazy: start-up

        for obj in list(namespace.values()):
            if isinstance(obj, CPUDispatcher):
                obj._cache = NullCache()
        return call()


@contextmanager
def environment(name: str, value: str | None) -> Iterator[None]:
    """Within the block, ``name`` is ``value`` in this process's environment (and so in the workers
    it starts); None changes nothing. How a build points its workers at its cache's folders."""
    if value is None:
        yield
        return
    old = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = old
