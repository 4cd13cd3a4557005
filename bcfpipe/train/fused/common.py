"""What the fused step's implementations share: the feature-source codes they dispatch on, and the
cache folder their compiled code lives in (neither needs numba or a compiler to import)."""
from __future__ import annotations

import os
from pathlib import Path

FREE_BC6H, FREE_BC7, BLOCK_BC6H, BLOCK_BC7 = 0, 1, 2, 3  # free texels (warm-up) or blocks, per format
# A slot's first field: not sampled, a trained level, or a fixed one: a level written as it was
# encoded (a T_0 of principal components, BC7 in any mode), its UNORM8 values stored like free
# texels, sampled with no gradient.
INACTIVE, TRAINED, FIXED = 0, 1, 2


KERNELS_ENV = "BCFPIPE_KERNELS"  # set by a build for its workers: the kernels of the build's cache


def kernels_dir() -> str:
    """Compiled kernels live in bcfpipe's cache (``kernels/``): the build's (``--cache``), else the
    default one; never beside the package or in numba's default places. NUMBA_CACHE_DIR, when set,
    wins."""
    from bcfpipe.config import default_cache_root

    return (os.environ.get("NUMBA_CACHE_DIR") or os.environ.get(KERNELS_ENV)
            or str(default_cache_root() / "kernels"))


def kernels_in(cache_root: str | os.PathLike | None):
    """Within the block (a context manager), this process and the workers it starts keep compiled
    kernels under ``cache_root/kernels`` (a build's --cache); None changes nothing."""
    from bcfpipe.config import environment

    return environment(KERNELS_ENV, None if cache_root is None else str(Path(cache_root) / "kernels"))
