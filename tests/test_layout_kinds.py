"""A new kind of layout candidate is one class (issue 51): registered beside the shipped kinds, with
`decide_layout` and `export_layout` as they are, its candidate is weighed, and when it wins it is
written by its own `export`."""
from __future__ import annotations

import numpy as np
import pytest

from bcfpipe.config import TrainingOptions
from bcfpipe.export import writer as E
from bcfpipe.formats import material as mf
from bcfpipe.formats.bcn import ClassicFormat
from bcfpipe.layout import choose as C
from bcfpipe.layout import kinds as K
from bcfpipe.layout.classic import Group, channel_errors, encode_bc7
from bcfpipe.layout.export import export_groups, export_layout
from bcfpipe.layout.decide import decide_layout
from bcfpipe.texset.metrics import mse_per_channel
from bcfpipe.texset.texture_set import Channel, TextureSet, build_mip_chain

from test_classic_layout import _set

OPTIONS = TrainingOptions(profile="tiny", preset="smoke", device="cpu", threads=1, seed=0, layout="auto")


class EveryGroupBC7(K.Kind):
    """BC@R with every group re-encoded as BC7 (test only): measured exactly, as the repacks are,
    and written from its own encoded textures (`Weighed.parts`). Its normal is x, y as decoders read
    them (z rebuilt), not the slopes a UsdUVTexture reads: a kind to test the registry, not to ship."""

    name = "every group bc7"

    def __init__(self) -> None:
        self.exports = 0

    def label(self, c: C.Candidate) -> str:
        return "BC@R with every group as BC7"

    def predict(self, ctx: K.FitContext) -> list[K.Weighed]:
        ts = ctx.ts
        ref = build_mip_chain(ts.data)
        enc = [encode_bc7(ts, Group(ClassicFormat.BC7, g.group.channels, g.group.name), ctx.resolution, ref, ctx.wrap)
               for g in ctx.classic.groups]
        e = channel_errors(ts, enc, ref)
        c = C.Candidate(tuple(g.group.name for g in enc), None, sum(g.size_bytes for g in enc),
                        C.combine(None, e, range(ts.num_channels)), "measured", ctx.classic.use, kind=self)
        return [K.Weighed(c, parts=enc)]

    def export(self, fit, c, ts, out, wrap):
        self.exports += 1
        return export_groups(fit, fit.parts, ts, out, wrap)


def _normal_set(size: int = 64) -> TextureSet:
    """A normal map alone (BC5 slopes in BC@R) whose x and y move together within a block: BC7's 16 index
    levels on one line hold it better than BC5's 8 per channel, in the same bytes (each 16 a block)."""
    yy, xx = np.mgrid[0:size, 0:size] / size
    nx = 0.5 * np.sin(6.28 * xx)
    data = np.stack([nx, 0.8 * nx + 0.05 * yy], -1).astype(np.float32)
    ch = (Channel("normal", "x", "normal", "n.png", 0), Channel("normal", "y", "normal", "n.png", 1))
    return TextureSet(data, ch, size, size)


@pytest.fixture
def bc7_kind(monkeypatch):
    """The test kind registered after the shipped ones; monkeypatch restores the registry."""
    kind = EveryGroupBC7()
    monkeypatch.setattr(K, "REGISTRY", (*K.REGISTRY, kind))
    return kind


def _labels(d: C.Decision) -> list[str]:
    return [c.label for c in d.candidates]


def test_a_registered_kind_that_wins_is_weighed_chosen_and_exported_by_its_own_export(bc7_kind, tmp_path):
    ts = _normal_set()
    fit = decide_layout(ts, tmp_path / "work", OPTIONS, 64)
    mine = next(c for c in fit.decision.candidates if c.kind is bc7_kind)
    assert "BC@R with every group as BC7" in _labels(fit.first) and mine.label in _labels(fit.decision)
    assert mine.size_bytes == fit.decision.bc.size_bytes  # BC7 and BC5 both hold 16 bytes a block
    assert fit.decision.chosen is mine and mine.psnr > fit.decision.bc.psnr
    out = export_layout(fit, ts, tmp_path / "m", "repeat")
    assert bc7_kind.exports == 1
    desc = mf.read(out)
    assert [t.format for t in desc.classic] == ["BC7_UNORM"] and not desc.neural
    ref = build_mip_chain(ts.data)  # the folder decodes to what the kind measured
    got = mse_per_channel(ref, E.decode_mips(E.load(out), [m.shape[:2] for m in ref]), ts.channels).mean(1)
    np.testing.assert_allclose(got, mine.mse_per_mip, rtol=1e-5)


def test_a_registered_kind_that_loses_is_weighed_and_rejected(bc7_kind, tmp_path):
    """On a BC1 + BC5 normal + BC4 set every group in BC7 takes more than BC@R's bytes: weighed, never shipped."""
    fit = decide_layout(_set(), tmp_path / "work", OPTIONS, 64)
    rows = {c["layout"]: c for c in fit.decision.to_json()["candidates"]}
    assert "MiB > BC@R's" in rows["BC@R with every group as BC7"]["rejected"]
    assert fit.decision.chosen.kind is not bc7_kind and bc7_kind.exports == 0


def test_the_shipped_kinds_label_their_candidates():
    use = (0,)
    bc = C.Candidate(("albedo", "normal"), None, 1, (1.0,), "measured", use, kind=K.BC_AT_R)
    assert [k.name for k in K.REGISTRY] == ["bc@r", "repack", "neural", "mixed", "split"]
    assert bc.label == C.ALL_CLASSIC
    assert C.Candidate(("normal", "albedo+roughness"), None, 1, (1.0,), "measured", use, K.Repacked("albedo+roughness as BC7"),
                       kind=K.REPACK).label == "BC@R with albedo+roughness as BC7"
    assert C.Candidate((), "1k", 1, (1.0,), "predicted", use, K.NeuralPart(), kind=K.NEURAL).label == "neural 1k"
    assert C.Candidate(("normal",), "1k", 1, (1.0,), "predicted", use, K.NeuralPart(2),
                       kind=K.MIXED).label == "neural 1k, T_0 of 2 layers + classic normal"
    split = C.Candidate(bc.classic, "8/8/8/4", 1, (1.0,), "predicted", use, K.SplitPart(2, (8, 8, 8, 4)),
                        kind=K.SPLIT)
    assert split.label == "BC@R below mip 2 + neural 8/8/8/4 from it"
    assert "kind" not in split.to_json(bc) and split == C.Candidate(**{**split.__dict__, "kind": None})
