"""What the fused step's implementations share: the feature-source codes they dispatch on, and the
cache folder their compiled code lives in (neither needs numba or a compiler to import)."""
from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

FREE_BC6H, FREE_BC7, BLOCK_BC6H, BLOCK_BC7 = 0, 1, 2, 3  # free texels (warm-up) or blocks, per format


KERNELS_ENV = "BCFPIPE_KERNELS"  # set by a build for its workers: the kernels of the build's cache


def kernels_dir() -> str:
    """Compiled kernels live in bcfpipe's cache (``kernels/``): the build's (``--cache``), else the
    default one; never beside the package or in numba's default places. NUMBA_CACHE_DIR, when set,
    wins."""
    from bcfpipe.config import default_cache_root

    return (os.environ.get("NUMBA_CACHE_DIR") or os.environ.get(KERNELS_ENV)
            or str(default_cache_root() / "kernels"))


@contextmanager
def kernels_in(cache_root: str | os.PathLike | None) -> Iterator[None]:
    """Within the block, this process and the workers it starts keep compiled kernels under
    ``cache_root/kernels`` (a build's --cache); None changes nothing."""
    if cache_root is None:
        yield
        return
    old = os.environ.get(KERNELS_ENV)
    os.environ[KERNELS_ENV] = str(Path(cache_root) / "kernels")
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(KERNELS_ENV, None)
        else:
            os.environ[KERNELS_ENV] = old
