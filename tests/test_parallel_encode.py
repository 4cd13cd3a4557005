"""BC encodes on OpenMP threads or in bands over processes (quicktex) and threads (ISPC) give the bytes of one encode
(bcfpipe.texset.parallel, issue 50)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bcfpipe.texset import parallel


@pytest.fixture
def two_workers():
    parallel.set_encode_workers(2)
    yield
    parallel.set_encode_workers(None)
    parallel.release_workers()


def _texels(h: int, w: int, seed: int = 0) -> np.ndarray:
    """Smooth gradients with noise: blocks whose endpoints differ from band to band."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    base = np.stack([x, y, (x + y) / 2, 1 - x], -1) * 200
    return np.clip(base + rng.normal(0, 20, base.shape), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("codec,block", [("bc1 level 18", 8), ("bc4 channel 0", 8), ("bc5 channels 0 1", 16)])
def test_quicktex_on_any_workers_equals_one_encode(two_workers, codec, block):
    """On the main thread quicktex's own OpenMP threads (2, then 1), beside a training its bands in
    2 processes: the bytes of one plain encode every time."""
    import threading

    import quicktex

    px = _texels(768, 512)
    assert px.shape[0] > parallel.BAND_ROWS
    whole = parallel.make_quicktex_encoder(codec).encode(quicktex.RawTexture.frombytes(px.tobytes(), 512, 768))
    two = parallel.quicktex_level(codec, px, block)
    parallel.set_encode_workers(1)
    one = parallel.quicktex_level(codec, px, block)
    parallel.set_encode_workers(2)
    aside: list = []
    th = threading.Thread(target=lambda: aside.append(parallel.quicktex_level(codec, px, block)))
    th.start()
    th.join()
    assert parallel._pool is not None  # the bands went to processes
    assert two.shape == (768 * 512 // 16, block)
    assert two.tobytes() == one.tobytes() == aside[0].tobytes() == whole.tobytes()


def test_bc7_threads_equal_one_thread():
    from bcfpipe.texset.baselines import _ispc_bc7_levels

    m = _texels(520, 300, 1).astype(np.float32) / 255.0
    parallel.set_encode_workers(1)
    try:
        one = _ispc_bc7_levels([m])[0]
        parallel.set_encode_workers(2)
        two = _ispc_bc7_levels([m])[0]
    finally:
        parallel.set_encode_workers(None)
    assert two.tobytes() == one.tobytes() and one.shape == (130 * 75, 16)


def test_job_encode_workers_share_the_cores(monkeypatch):
    monkeypatch.setattr(parallel, "_cores", lambda: 2)  # no --jobs: the machine's cores
    assert parallel.job_encode_workers(1, 1) == 2  # one material: both cores encode
    assert parallel.job_encode_workers(1, 2) == 1  # two side by side: one each
    assert parallel.job_encode_workers(3, 2) == 3  # never fewer than --threads


@pytest.mark.parametrize("layout", [("--layout", "auto"), ("--layout", "neural", "--classic", "normal")])
def test_layout_fit_says_how_long_its_encodes_took(tmp_path, layout):
    """`train` with a layout fit on two cores (auto: BC@R encodes in a thread beside the probe's
    training; neural with --classic: before its one training): the result says how long the encodes
    took apart from training; auto's folder holds BC@R's bytes or fewer."""
    import json

    from click.testing import CliRunner

    from bcfpipe.cli import main

    t = Path(__file__).resolve().parents[1] / "samples" / "textures"
    parallel.set_encode_workers(2)
    try:
        r = CliRunner().invoke(main, ["train", f"albedo={t / 'bricks_albedo.png'}:rgb",
                                      f"normal={t / 'bricks_normal.png'}:xy", *layout, "--profile", "tiny",
                                      "--quality", "smoke", "--threads", "1", "-o", str(tmp_path / "m"), "--json"])
    finally:
        parallel.set_encode_workers(None)
        parallel.release_workers()
    assert r.exit_code == 0, r.output
    d = json.loads(r.stdout.strip().splitlines()[-1])
    assert d["phase_seconds"]["classic_encode"] > 0
    if "auto" in layout:  # the default objective: never more than BC@R's bytes
        assert d["size_bytes"] <= d["layout"]["bc"]["size_bytes"]
