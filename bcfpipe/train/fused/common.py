"""What the fused step's implementations share: the feature-source codes they dispatch on, and the
cache folder their compiled code lives in (neither needs numba or a compiler to import)."""
from __future__ import annotations

import os

FREE_BC6H, FREE_BC7, BLOCK_BC6H, BLOCK_BC7 = 0, 1, 2, 3  # free texels (warm-up) or blocks, per format


def kernels_dir() -> str:
    """Compiled kernels live in bcfpipe's cache (``kernels/``), never beside the package or in
    numba's default places; NUMBA_CACHE_DIR, when set, wins."""
    from bcfpipe.config import default_cache_root

    return os.environ.get("NUMBA_CACHE_DIR") or str(default_cache_root() / "kernels")
