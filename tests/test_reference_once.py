"""Issue 58: one reference chain and one set of coverage masks per material per fit, and the
evaluation's progress step by step."""
from __future__ import annotations

import inspect
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.config import TrainingOptions
from bcfpipe.export.material import FIGURES, train_material, make_config
from bcfpipe.layout.decide import decide_layout
from bcfpipe.texset.chain import Reference
from bcfpipe.texset.texture_set import TextureSpec, load_texture_set

SAMPLES = Path(__file__).resolve().parents[1] / "samples" / "textures"
OPTIONS = TrainingOptions(profile="tiny", preset="smoke", seed=0, device="cpu", threads=1, layout="neural")


@pytest.fixture(scope="module")
def bricks():
    """The sample bricks (albedo, normal, roughness: real PNGs) at 64²."""
    return load_texture_set([TextureSpec.parse(f"albedo={SAMPLES / 'bricks_albedo.png'}:rgb"),
                             TextureSpec.parse(f"normal={SAMPLES / 'bricks_normal.png'}:xy"),
                             TextureSpec.parse(f"roughness={SAMPLES / 'bricks_roughness.png'}:r")], resolution=64)


@pytest.fixture(scope="module")
def coverage():
    """The left half and a few texels of the right one: a mask, not every texel."""
    m = np.zeros((64, 64), bool)
    m[:, :32] = True
    m[40:44, 50:54] = True
    return m


def _spy(monkeypatch, module: str, name: str) -> list:
    """Count the calls of ``module.name`` wherever it is reachable: the function itself and every
    loaded module that imported it by name (the real function still runs)."""
    real = getattr(sys.modules[module], name)
    calls = []

    def spy(*a, **k):
        calls.append(a)
        return real(*a, **k)

    for mod in list(sys.modules.values()):
        if getattr(mod, name, None) is real:
            monkeypatch.setattr(mod, name, spy)
    return calls


def _counted(monkeypatch) -> tuple[list, list]:
    import bcfpipe.scan.coverage  # noqa: F401  (loaded, so that its mask_mips can be wrapped)

    return (_spy(monkeypatch, "bcfpipe.texset.texture_set", "build_mip_chain"),
            _spy(monkeypatch, "bcfpipe.scan.coverage", "mask_mips"))


def test_fit_material_builds_one_chain_and_one_set_of_masks(tmp_path, monkeypatch, bricks, coverage):
    _, cfg = make_config(bricks, OPTIONS)
    chains, masks = _counted(monkeypatch)
    res, _ = train_material(bricks, tmp_path / "m", cfg, "tiny", coverage=coverage, measure=FIGURES)
    assert len(chains) == 1 and len(masks) == 1
    assert res.metrics.psnr_covered is not None and 0.0 < res.metrics.covered_fraction < 1.0


def test_a_passed_reference_is_used_and_changes_nothing(tmp_path, monkeypatch, bricks, coverage):
    _, cfg = make_config(bricks, OPTIONS)
    own, _ = train_material(bricks, tmp_path / "own", cfg, "tiny", coverage=coverage)
    ref = Reference.of(bricks, coverage, cfg.model.wrap)
    chains, masks = _counted(monkeypatch)
    given, _ = train_material(bricks, tmp_path / "given", cfg, "tiny", coverage=coverage, reference=ref)
    assert chains == [] and masks == []  # nothing built again
    assert given.metrics == own.metrics and given.float_metrics == own.float_metrics
    np.testing.assert_array_equal(given.mse_per_channel, own.mse_per_channel)
    files = sorted(p.name for p in (tmp_path / "own").iterdir())
    assert files == sorted(p.name for p in (tmp_path / "given").iterdir())
    for name in files:
        assert (tmp_path / "own" / name).read_bytes() == (tmp_path / "given" / name).read_bytes(), name


def test_a_reference_of_something_else_is_refused(tmp_path, bricks, coverage):
    _, cfg = make_config(bricks, OPTIONS)
    with pytest.raises(ValueError, match="coverage"):  # masks held, no coverage given
        train_material(bricks, tmp_path / "a", cfg, coverage=None, reference=Reference.of(bricks, coverage))
    half = Reference.of(load_texture_set([TextureSpec.parse(f"albedo={SAMPLES / 'bricks_albedo.png'}:rgb")],
                                         resolution=32))
    with pytest.raises(ValueError, match="set"):
        train_material(bricks, tmp_path / "b", cfg, reference=half)


def test_evaluate_reports_steps_and_an_eta(tmp_path, bricks):
    _, cfg = make_config(bricks, OPTIONS)
    seen = []
    train_material(bricks, tmp_path / "m", cfg, "tiny", progress=seen.append, measure=FIGURES)
    ev = [p for p in seen if p.phase == "evaluate"]
    mips = 7  # 64² .. 1²
    assert ev[0].steps == 0  # it starts before there is a rate to estimate from
    counted = [p for p in ev if p.steps]
    assert {p.steps for p in counted} == {mips + 1}
    assert [p.step for p in counted] == sorted(p.step for p in counted)
    assert set(range(1, mips + 2)) <= {p.step for p in counted}  # each mip decoded, then the metrics
    assert all(math.isfinite(p.eta) and p.eta >= 0.0 for p in counted) and counted[-1].eta == 0.0
    assert all(b.elapsed >= a.elapsed for a, b in zip(ev, ev[1:]))


def test_evaluate_line_in_the_train_command():
    """What `bcfpipe train` prints for an evaluation step (bcfpipe.cli.train._line)."""
    from bcfpipe.cli.train import _line
    from bcfpipe.train.progress import Progress

    line = _line(Progress("evaluate", 3, 12, float("nan"), float("nan"), 80.0, 9.4), 80.0)
    assert line.split() == ["evaluate", "3/12", "elapsed", "1m20s", "eta", "9s"]


@pytest.mark.skipif("reference" not in inspect.signature(decide_layout).parameters, reason="decide_layout takes no reference yet (its owner adds it, issue 58)")
def test_layout_fit_builds_one_chain_and_one_set_of_masks(tmp_path, monkeypatch, bricks, coverage):
    from bcfpipe.layout.material import layout_material

    chains, masks = _counted(monkeypatch)
    opts = TrainingOptions(profile="tiny", preset="smoke", seed=0, device="cpu", threads=1, layout="auto")
    res = layout_material(bricks, tmp_path / "m", opts, "repeat", coverage=coverage)
    assert res.metrics.psnr_covered is not None
    assert len(chains) == 1 and len(masks) == 1
