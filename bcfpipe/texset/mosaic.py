"""A level's 4×4 blocks, and blocks laid side by side as a level of their own (a mosaic).

Every BC format encodes a block on its own, so a mosaic of some of a level's blocks encodes to
those blocks' bytes: the layout's sampled estimates (`bcfpipe.layout.estimate`) and the encode of
each distinct block once (`bcfpipe.texset.distinct_blocks`) both encode one.
"""
from __future__ import annotations

import numpy as np


def block_grid(img: np.ndarray) -> np.ndarray:
    """``img`` ((H, W, ...) of whole blocks) as its (H/4, W/4, 4, 4, ...) blocks: a view."""
    h, w = img.shape[:2]
    tail = img.shape[2:]
    return np.moveaxis(img.reshape((h // 4, 4, w // 4, 4) + tail), 2, 1)


def mosaic(blocks: np.ndarray, columns: int) -> np.ndarray:
    """(n, 4, 4, ...) blocks as a level, ``columns`` per row (fewer when there are fewer), in order,
    the last row filled with the first block again."""
    n, cols = len(blocks), min(columns, len(blocks))
    rows = -(-n // cols)
    filled = np.concatenate([blocks, np.repeat(blocks[:1], rows * cols - n, 0)])
    tail = blocks.shape[3:]
    laid = np.moveaxis(filled.reshape((rows, cols, 4, 4) + tail), 2, 1)
    return np.ascontiguousarray(laid.reshape((rows * 4, cols * 4) + tail))
