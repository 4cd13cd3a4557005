"""The layout's classic estimates (issue 58): a sample of blocks encoded as the shipping encoder
encodes them, whose error is the level's; with every block the full encode's error exactly; and
what ships is encoded in full, once, and measured."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bcfpipe.config import TrainingOptions
from bcfpipe.layout import classic as L
from bcfpipe.layout import estimate as E
from bcfpipe.layout.classic_fit import ClassicWork, estimated, measure
from bcfpipe.layout.kinds import CLASSIC
from bcfpipe.texset.chain import Reference
from bcfpipe.texset.metrics import psnr_from_mse
from bcfpipe.texset.texture_set import TextureSpec, build_mip_chain, load_texture_set

SAMPLE = Path(__file__).resolve().parents[1] / "samples" / "textures"


@pytest.fixture(scope="module")
def bricks():
    """The sample's bricks (512²): albedo BC1, normal BC5 slopes, roughness BC4."""
    return load_texture_set([TextureSpec.parse(f"albedo={SAMPLE / 'bricks_albedo.png'}:rgb"),
                             TextureSpec.parse(f"normal={SAMPLE / 'bricks_normal.png'}:xy"),
                             TextureSpec.parse(f"roughness={SAMPLE / 'bricks_roughness.png'}:r")])


def test_the_draw_is_one_block_per_cell_fixed_and_whole_where_small():
    s = E.draw([(1024, 1024), (512, 512), (256, 256), (6, 6)], budget=4096)
    big, mid, small, odd = s.picks
    assert small is None and odd is None  # 4096 blocks and under, and sides not multiples of 4: whole
    assert len(big) == 4096 and len(mid) == 4096  # s = 4 and 2: one block in each s x s cell
    cells = {(r // 4, c // 4) for r, c in big}
    assert len(cells) == 4096 and big.min() >= 0 and big.max() < 256
    assert all((a == b).all() for a, b in zip(s.picks[:2], E.draw([(1024, 1024), (512, 512), (256, 256), (6, 6)],
                                                                    budget=4096).picks[:2]))
    assert E.draw([(1024, 1024)], whole_first=True, budget=4096).picks == (None,)


def test_a_mosaic_encodes_to_the_levels_own_blocks(bricks):
    """Block-local encoders: each drawn block's bytes in the mosaic are its bytes in the full level."""
    level = build_mip_chain(bricks.data)[0]
    g = L.groups(bricks)[0]  # albedo, BC1 (quicktex level 18)
    full, mosaic = [], []
    L.group_texels(bricks, g, [level], full)
    pick = E.draw([level.shape[:2]], budget=512).picks[0]
    L.group_texels(bricks, g, [E.gather(level, pick)], mosaic)
    blocks_full = full[0][0].reshape(128, 128, 8)
    got = mosaic[0][0][:len(pick)]
    np.testing.assert_array_equal(got, blocks_full[pick[:, 0], pick[:, 1]])


def test_every_block_drawn_is_the_full_encode_exactly(bricks):
    ref = build_mip_chain(bricks.data)
    for r in (512, 256):  # at R = 256 level 0 is magnified over mip 0
        enc = L.encode(bricks, r, ref)
        e, frac = E.estimate_errors(bricks, [g.group for g in enc], r, ref, budget=10 ** 9)
        assert frac == 1.0
        np.testing.assert_array_equal(e, L.channel_errors(bricks, enc, ref))


def test_a_sampled_estimate_is_within_a_tenth_of_a_db_per_mip(bricks):
    ref = build_mip_chain(bricks.data)
    enc = L.encode(bricks, 512, ref)
    exact = L.channel_errors(bricks, enc, ref).mean(1)
    e, frac = E.estimate_errors(bricks, [g.group for g in enc], 512, ref, budget=4096)  # level 0: 1 block in 4
    assert frac < 0.5
    diff = [psnr_from_mse(a) - psnr_from_mse(b) for a, b in zip(e.mean(1), exact)]
    assert max(abs(d) for d in diff) < 0.1, diff


def test_measure_encodes_what_ships_once_and_replaces_the_estimate(bricks):
    work = ClassicWork(bricks, 512, Reference.of(bricks), "repeat", CLASSIC)
    est = estimated(work, whole_bc=False)
    assert est.bc.basis == "estimated" and not est.measured and all(not g.encoded for g in est.groups)
    assert all(p.basis == "estimated" for p in est.packed)
    exact_bytes = sum(g.size_bytes for g in L.encode(bricks, 512, build_mip_chain(bricks.data)))
    assert est.bc.size_bytes == exact_bytes  # sizes are exact before any encode
    rp = est.packed[0]
    got = measure(work, est, rp)
    shipped = next(p for p in got.packed if p.part == rp.part)
    assert shipped.basis == "measured" and shipped.disk_bytes
    kept = [g for g in got.groups if g.group.name not in got.repacked[rp.part.repack][0].replaces]
    assert kept and all(g.encoded for g in kept)  # only what the repack ships was encoded
    assert not got.measured and got.bc.basis == "estimated"
    bc = measure(work, got)
    assert bc.measured and bc.bc.basis == "measured"


def test_the_default_layout_ships_a_measured_candidate_and_says_what_each_part_cost(tmp_path):
    """The probe's all-channel candidate is predicted from it with the measured gain of a full
    training per mip (`gains.PROBE_GAINS_DB`), and a classic first choice trains nothing."""
    from bcfpipe.layout import kinds as K
    from bcfpipe.layout.export import decision_json
    from bcfpipe.layout.decide import decide_layout
    from bcfpipe.texset.metrics import psnr_from_mse
    from bcfpipe.train.gains import probe_gains

    from test_classic_layout import _set

    opts = TrainingOptions(profile="tiny", preset="smoke", device="cpu", threads=1, seed=0, layout="auto")
    ts = _set(64)
    fit = decide_layout(ts, tmp_path / "work", opts, 64)
    assert fit.decision.chosen.basis == "measured"
    d = decision_json(fit)
    assert set(fit.costs) >= {"estimate", "probe", "classic_encode"}
    assert {c["basis"] for c in d["weighed"]} == {"estimated", "predicted"}
    probe = fit.probe
    own = next(c for c in fit.first.candidates if c.profile == probe.profile and not c.classic
               and c.part == K.NeuralPart(probe.t0_layers))
    t0_mip = max(0, (max(ts.width, ts.height) // probe.resolutions[0]).bit_length() - 1)
    gains = probe_gains("smoke", probe.mse_per_channel.shape[0], t0_mip)
    for k in own.use:
        assert own.psnr_per_mip[k] - psnr_from_mse(float(probe.mse_per_channel[k].mean())) == pytest.approx(gains[k])
    if fit.first.chosen.profile is None:  # classic first: no training but the probe
        assert "train" not in fit.costs and fit.neural is None


def test_a_sampled_measure_decodes_the_texels_it_names_exactly(tmp_path):
    """`writer.decode_mips` with ``texels`` gives those texels of the whole decode, bit for bit; a
    sampled measure takes one texel in each 2x2 cell of a large mip, or each 4x4 cell where a quarter
    is over `SAMPLED_MOST`, every place within a cell."""
    from bcfpipe.export import writer as E
    from bcfpipe.export.material import Measure, train_material, make_config, sampled_texels

    from test_classic_layout import _set

    ts = _set(64)
    cfg = make_config(ts, TrainingOptions(profile="tiny", preset="smoke", device="cpu", threads=1, seed=0))[1]
    res = train_material(ts, tmp_path / "m", cfg, "tiny", measure=Measure(image_metrics=False, float_model=False))[0]
    em = E.load(res.out_dir)
    shapes = [(64, 64), (32, 32)]
    picks = [np.array([0, 5, 64 * 10 + 3, 64 * 64 - 1]), None]
    whole = E.decode_mips(em, shapes)
    part = E.decode_mips(em, shapes, texels=picks)
    assert np.array_equal(part[0][:, 0], whole[0].reshape(-1, whole[0].shape[-1])[picks[0]])
    assert np.array_equal(part[1], whole[1])
    big, mid, small = sampled_texels([(2048, 1024), (1024, 512), (512, 512)])
    assert small is None and len(mid) == 1024 * 512 // 4 and len(big) == 2048 * 1024 // 16
    for picked, (h, w), k in ((mid, (1024, 512), 2), (big, (2048, 1024), 4)):
        y, x = picked // w, picked % w
        assert len(np.unique((y // k) * (w // k) + x // k)) == len(picked)  # one per kxk cell
        assert {(a, b) for a, b in zip(y % k, x % k)} == {(a, b) for a in range(k) for b in range(k)}


@pytest.mark.parametrize("detail", [False, True])
def test_the_oracle_holds_predictions_at_the_mips_finer_than_t0(detail):
    """A 256² set at a 64² T_0: smooth, its 64² mip magnified holds mips 0 and 1 within 0.1 dB of
    nothing lost; with texel-scale detail it loses far more, and a prediction there is held to it."""
    from bcfpipe.layout.oracle import ORACLE_MARGIN_DB, cap, magnified_errors
    from bcfpipe.texset.metrics import psnr_from_mse

    ts = _smooth_or_detailed(detail)
    e = magnified_errors(Reference.of(ts), 64, ts.channels, "repeat")
    assert e.shape[0] == len(Reference.of(ts).mips) and not e[2:].any()  # mip 2 is T_0's own size
    assert (psnr_from_mse(float(e[0, 0])) < 25) == detail and (psnr_from_mse(float(e[0, 0])) > 40) == (not detail)
    held = cap(np.full_like(e, 1e-9), e)
    assert np.allclose(held[:2], e[:2] * 10 ** (-ORACLE_MARGIN_DB / 10)) and np.all(held[2:] == 1e-9)


@pytest.mark.parametrize("wrap", ["repeat", "clamp", "mirror", ("repeat", "clamp")])
@pytest.mark.parametrize("drawn", [False, True])
def test_the_oracle_kernel_measures_the_magnified_mip_as_numpy_does(wrap, drawn):
    """`oracle_kernel.magnified_sse` against numpy: the whole mip magnified (`classic.magnify`), read at
    the texels drawn (the edges among them) or at every one, those a mask keeps, an HDR channel in its
    log domain (`encoding.encode`), the squared errors summed in float64."""
    from bcfpipe.layout.oracle_kernel import magnified_sse
    from bcfpipe.texset import encoding

    rng = np.random.default_rng(3)
    src = rng.random((16, 32, 3), dtype=np.float32)
    truth = rng.random((64, 128, 3), dtype=np.float32)
    mask = rng.random((64, 128)) < 0.7
    gains = np.array([0.0, 3.5, 0.0], np.float32)
    corners = [0, 63 * 128 + 127, 127, 63 * 128]
    picks = np.concatenate([corners, rng.choice(64 * 128, 500, replace=False)]) if drawn else None
    sse, n = magnified_sse(src, truth, picks, mask, gains, wrap)
    at = np.arange(64 * 128) if picks is None else picks
    at = at[mask.reshape(-1)[at]]
    up = L.magnify(src, 64, 128, wrap).reshape(-1, 3)[at]
    ref = truth.reshape(-1, 3)[at]
    up[:, 1], ref[:, 1] = encoding.encode(up[:, 1], 3.5), encoding.encode(ref[:, 1], 3.5)
    assert n == len(at)
    assert np.allclose(sse, ((up.astype(np.float64) - ref) ** 2).sum(0), rtol=1e-5)


def test_the_sampled_oracle_is_within_a_twentieth_of_a_db_of_every_texels():
    """A 1024² mip holds 2^20 texels, over `oracle.SAMPLED_TEXELS`: measured on one texel in each
    2x2 cell, its oracle stays within 0.05 dB of the whole mip's, channel by channel."""
    from bcfpipe.layout import oracle as O

    ts = _smooth_or_detailed(True, 1024)
    ref = Reference.of(ts)
    drawn = O.magnified_errors(ref, 128, ts.channels, "repeat")
    whole = O.magnified_errors(ref, 128, ts.channels, "repeat", sampled_above=1 << 40)
    assert drawn[:3].all() and np.abs(10 * np.log10(drawn[:3] / whole[:3])).max() < 0.05


@pytest.mark.parametrize("detail", [False, True])
def test_no_probe_when_the_oracle_rules_out_every_neural_candidate(detail, tmp_path):
    """A 256² set at R = 256 with a 64² T_0 (tiny): with texel-scale detail, mips 0 and 1 magnified
    from T_0 fall far below BC@R's floor whatever a model holds, so nothing neural is trained, not
    even the probe; smooth, the probe trains."""
    from bcfpipe.layout.decide import decide_layout

    ts = _smooth_or_detailed(detail)
    opts = TrainingOptions(profile="tiny", preset="smoke", device="cpu", threads=1, seed=0, layout="auto")
    seen: list[str] = []
    fit = decide_layout(ts, tmp_path / "work", opts, 256, log=seen.append)
    assert (fit.probe is None) == detail and ("probe" in fit.costs) == (not detail)
    assert any(s.startswith("no probe: no neural candidate") for s in seen) == detail
    assert fit.decision.chosen.basis == "measured"


def test_the_largest_gain_is_at_least_the_mean_at_every_place():
    """`PROBE_GAINS_MAX_DB` is the most any measured set gained, `PROBE_GAINS_DB` their mean."""
    from bcfpipe.train.gains import PROBE_GAINS_DB, PROBE_GAINS_MAX_DB, probe_gains

    assert set(PROBE_GAINS_MAX_DB) == set(PROBE_GAINS_DB)
    for preset in PROBE_GAINS_DB:
        assert all(m >= g for m, g in zip(PROBE_GAINS_MAX_DB[preset], PROBE_GAINS_DB[preset])), preset
    assert probe_gains("draft", 4, 1, most=True) == [0.76, 2.06, 2.27, 2.34]


def _smooth_or_detailed(detail: bool, side: int = 256):
    """A ``side``² roughness map: a smooth wave, or the same with texel-scale noise."""
    from bcfpipe.texset.texture_set import Channel, TextureSet

    yy, xx = np.mgrid[0:side, 0:side] / side
    v = 0.5 + 0.3 * np.sin(6.28 * xx) * np.cos(6.28 * yy)
    if detail:
        v = v + 0.2 * np.random.default_rng(0).standard_normal(v.shape)
    return TextureSet(np.clip(v, 0, 1)[..., None].astype(np.float32),
                      (Channel("roughness", "r", "scalar", "r.png", 0),), side, side)


def test_the_quality_set_estimated_aside_is_the_one_estimated_before_the_rest(tmp_path):
    """With a core to spare the BC7 quality set is estimated on a thread beside the rest of the fit
    (no decision reads it) and waited for by layout.json; with one core, inline before the probe.
    Either way it is `estimated`'s own, figure for figure, and the decision is the same."""
    from bcfpipe.layout import kinds as K
    from bcfpipe.layout.decide import decide_layout
    from bcfpipe.layout.export import decision_json
    from bcfpipe.texset import parallel

    from test_classic_layout import _set

    opts = TrainingOptions(profile="tiny", preset="smoke", device="cpu", threads=1, seed=0, layout="auto")
    ts = _set(64)
    fits = {}
    for cores in (2, 1):
        parallel.set_encode_workers(cores)
        try:
            fits[cores] = decide_layout(ts, tmp_path / str(cores), opts, 64)
        finally:
            parallel.set_encode_workers(None)
    aside, inline = (fits[c].resolved() for c in (2, 1))
    assert aside.probe is not None and "estimate_aside" in aside.costs
    assert "estimate_aside" not in inline.costs
    whole = estimated(ClassicWork(ts, 64, Reference.of(ts), "repeat", K.CLASSIC))
    for fit in (aside, inline):
        q = fit.decision.quality
        assert q.label == whole.quality.label == "BC7 quality set"
        assert q.psnr_per_mip == whole.quality.psnr_per_mip and q.size_bytes == whole.quality.size_bytes
        assert fit.first.quality is q
    assert decision_json(fits[2])["bc7_quality"] == decision_json(fits[1])["bc7_quality"] == \
        whole.quality.to_json(aside.decision.bc)
    assert aside.decision.chosen.label == inline.decision.chosen.label
    assert aside.decision.chosen.psnr_per_mip == inline.decision.chosen.psnr_per_mip
