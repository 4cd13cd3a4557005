"""Host tensors in transparent huge pages, for the large arrays the CPU trainer reads at random.

torch's CPU allocator maps a large tensor in 4 KiB pages; numpy's allocator asks Linux for
transparent huge pages (``madvise(MADV_HUGEPAGE)``, which this kernel's default ``madvise`` mode
requires). A centre batch reads 16,384 random texels of a 2048² level kept texel by texel (about
200 MB): in 4 KiB pages almost every read also walks the page table. In 2 MiB pages the teapot's
centre batches at 1k took 1.3 ms instead of 1.9 ms per step, before the rows were also
prefetched (docs/benchmarks.md, "The repeat modulo, and the targets' cache misses").
"""
from __future__ import annotations

import numpy as np
import torch

__all__ = ["empty"]


def empty(shape: tuple[int, ...], dtype: torch.dtype, device: torch.device | str = "cpu") -> torch.Tensor:
    """``torch.empty(shape, dtype=dtype, device=device)``, from numpy's allocator on the CPU."""
    if torch.device(device).type != "cpu" or dtype not in _NUMPY:
        return torch.empty(shape, dtype=dtype, device=device)
    return torch.from_numpy(np.empty(shape, dtype=_NUMPY[dtype]))


_NUMPY = {torch.float16: np.float16, torch.float32: np.float32, torch.float64: np.float64, torch.int32: np.int32,
          torch.int64: np.int64, torch.uint8: np.uint8}
