"""BC@R's blocks kept in a build's cache (bcfpipe.texset.blocks): read back only for the same texels
and encoder, never trusted when damaged, nothing written outside a build's cache."""
from __future__ import annotations

import numpy as np

from bcfpipe.texset.blocks import BlocksStore, blocks_in
from bcfpipe.cache.store import Cache
from bcfpipe.texset.baselines import bc1_mips, bc4_mips
from bcfpipe.texset.texture_set import build_mip_chain


def _mips(seed: int, c: int):
    rng = np.random.default_rng(seed)
    return build_mip_chain(rng.random((32, 16, c), dtype=np.float32))


def test_blocks_are_kept_per_input_and_encoder_and_read_back(tmp_path):
    cache = Cache(tmp_path / "c")
    mips = _mips(0, 3)
    plain_blocks: list = []
    plain, size = bc1_mips(mips, blocks=plain_blocks)
    assert not cache.blocks.files()  # outside a build's cache nothing is written
    with blocks_in(cache.base):
        first_blocks: list = []
        first, s1 = bc1_mips(mips, blocks=first_blocks)
        (f,) = cache.blocks.files()
        # the file is what is read: other (valid) blocks under the same key decode to their texels
        with np.load(f) as z:
            levels = [z[f"level{k}"] for k in range(len(mips))]
        np.savez(f, format=np.array("bcfpipe-bc-blocks-v1"), **{f"level{k}": np.zeros_like(b)
                                                               for k, b in enumerate(levels)})
        zeros, _ = bc1_mips(mips)
        assert all(np.array_equal(z, np.zeros_like(z)) for z in zeros)
        f.write_bytes(f.read_bytes()[:100])  # damaged: ignored, encoded again, rewritten whole
        again_blocks: list = []
        again, s2 = bc1_mips(mips, blocks=again_blocks)
        assert len(cache.blocks.files()) == 1 and cache.blocks.get(f.stem, len(mips)) is not None
        bc1_mips(mips, level=5)  # another encoder setting: another key
        bc4_mips([m[..., :1] for m in mips])  # another format
        bc1_mips(_mips(1, 3))  # other texels
        assert len(cache.blocks.files()) == 4
    for got, blocks, sz in ((first, first_blocks, s1), (again, again_blocks, s2)):
        assert sz == size and all(np.array_equal(a, b) for a, b in zip(got, plain))
        assert all(np.array_equal(a[0], b[0]) and a[1:] == b[1:] for a, b in zip(blocks, plain_blocks))
    assert cache.info()["bc_blocks"] == 4 and cache.info()["bc_blocks_bytes"] > 0
    assert cache.clear() == 0 and not cache.blocks.files()


def test_prune_removes_blocks_unused_that_long(tmp_path):
    cache = Cache(tmp_path / "c")
    with blocks_in(cache.base):
        bc1_mips(_mips(2, 3))
    (f,) = cache.blocks.files()
    assert cache.blocks.prune(older_than=3600.0) == 0 and f.exists()
    cache.prune(older_than=10.0, now=f.stat().st_mtime + 20.0)
    assert not f.exists()
    assert BlocksStore(tmp_path / "none").files() == []


def test_a_build_without_a_cache_keeps_no_blocks(tmp_path, monkeypatch):
    """`--no-cache` neither reads nor writes BC@R's blocks (the default layout measures BC@R)."""
    from pathlib import Path

    from click.testing import CliRunner

    from bcfpipe.cli import main

    root = tmp_path / "cache"
    monkeypatch.setenv("BCFPIPE_CACHE", str(root))
    sample = Path(__file__).resolve().parents[1] / "samples" / "sample_scene.usda"
    r = CliRunner().invoke(main, ["build", str(sample), "-o", str(tmp_path / "out"), "--quality", "smoke",
                                  "--jobs", "1", "--threads", "1", "--no-cache"])
    assert r.exit_code == 0, r.output
    assert not list(root.rglob("*.npz")) and not (root / "v1" / "bc-blocks").exists()
