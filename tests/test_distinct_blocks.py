"""A level whose blocks repeat is encoded as the mosaic of its distinct blocks: the very bytes of the
whole level's encode, by every encoder that goes through it (bcfpipe.texset.distinct_blocks, issue 58)."""
from __future__ import annotations

import numpy as np
import pytest

from bcfpipe.texset import baselines
from bcfpipe.texset import distinct_blocks as D
from bcfpipe.texset import parallel


def _repeating(h: int = 512, w: int = 768, seed: int = 1) -> np.ndarray:
    """(h, w, 4) uint8: noisy gradients, a flat region and a tile of 8x8 texels repeated, so that
    about half the blocks repeat and the rest are distinct."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    px = np.clip(np.stack([x, y, (x + y) / 2, 1 - x], -1) * 200 + rng.normal(0, 25, (h, w, 4)), 0, 255)
    px[: h // 3] = (40, 90, 160, 255)
    tile = rng.integers(0, 256, (8, 8, 4))
    px[h // 3: h // 2] = np.tile(tile, (-(-(h // 2 - h // 3) // 8), w // 8, 1))[: h // 2 - h // 3]
    return np.ascontiguousarray(px.astype(np.uint8))


@pytest.fixture
def one_worker():
    parallel.set_encode_workers(1)
    yield
    parallel.set_encode_workers(None)


def test_distinct_finds_each_block_once():
    px = _repeating()
    tiles, inverse = D.distinct(px)
    grid = px.reshape(128, 4, 192, 4, 4).transpose(0, 2, 1, 3, 4).reshape(-1, 4, 4, 4)
    blocks = tiles.reshape(tiles.shape[0] // 4, 4, tiles.shape[1] // 4, 4, 4).transpose(0, 2, 1, 3, 4).reshape(-1, 4, 4, 4)
    assert np.array_equal(blocks[inverse], grid)  # each block is the mosaic's block it is encoded as
    n = len(np.unique(inverse))
    assert n == len(np.unique(grid.reshape(len(grid), -1), axis=0))  # and no two of those are equal
    assert n < 0.6 * len(grid)


def test_no_search_where_it_cannot_pay():
    rng = np.random.default_rng(0)
    assert D.distinct(rng.integers(0, 256, (512, 512, 4), dtype=np.uint8)) is None  # every block distinct
    assert D.distinct(np.zeros((128, 128, 4), np.uint8)) is None  # 1,024 blocks: fewer than MIN_BLOCKS
    assert D.distinct(np.zeros((512, 512, 3), np.uint8)) is None  # 12-byte block rows: not hashed


def test_a_hash_collision_encodes_the_level_as_it_is(monkeypatch):
    """Blocks that share a hash but not their bytes are never merged."""
    px = _repeating()
    monkeypatch.setattr(D, "_hashes", lambda p: np.zeros(p.shape[0] // 4 * (p.shape[1] // 4), np.uint64))
    assert D.distinct(px) is None
    seen = []
    out = D.encode_distinct(lambda p: seen.append(p.shape) or np.zeros((p.shape[0] * p.shape[1] // 16, 8), np.uint8), px)
    assert seen == [px.shape] and len(out) == 128 * 192


@pytest.mark.parametrize("codec,block", [("bc1 level 13", 8), ("bc1 level 18", 8)])
def test_quicktex_bc1_bytes_are_the_whole_levels(one_worker, codec, block):
    px = _repeating()
    assert D.distinct(px) is not None
    assert np.array_equal(parallel.quicktex_level(codec, px, block), parallel._quicktex_level(codec, px, block))


def test_ispc_bc7_and_bc6h_bytes_are_the_whole_levels(one_worker, monkeypatch):
    px = _repeating()
    levels = [px.astype(np.float32) / 255]
    hdr = [px[..., :3].astype(np.float32) / 16]
    bc7 = baselines._ispc_bc7_levels(levels)[0]
    bc6h = baselines._ispc_bc6h_levels(hdr)[0]
    monkeypatch.setattr(D, "MAX_DISTINCT", -1.0)  # every level encoded as it is
    assert np.array_equal(bc7, baselines._ispc_bc7_levels(levels)[0])
    assert np.array_equal(bc6h, baselines._ispc_bc6h_levels(hdr)[0])


def test_real_albedo_bc1_bytes_are_the_whole_levels(one_worker, shared_scenes):
    """The water bottle's albedo: 41 % of its blocks distinct."""
    from PIL import Image

    px = np.asarray(Image.open(shared_scenes / "gltf_water_bottle" / "WaterBottle_baseColor.png").convert("RGBA"))
    px = np.ascontiguousarray(px[:1024, :1024])
    assert D.distinct(px) is not None
    assert np.array_equal(parallel.quicktex_level("bc1 level 13", px, 8),
                          parallel._quicktex_level("bc1 level 13", px, 8))
