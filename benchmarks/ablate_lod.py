"""Ablation behind the lod-bias rule and the s sampling: train a 512² teapot crop (profile
256/128/64/32, the same ratios as 1k on the 2048² set) under a variant, then sweep PSNR over lod.

  python benchmarks/ablate_lod.py NAME [--rule natural|span] [--extra 0,-1,-2,-2] [--int-frac 0.5]

--rule natural: b_i = log2(r_i / W) (every layer reaches 4x4 at the same s); span: the default
rule of bcfpipe.model.lod_biases. --extra adds per-layer offsets on top. --int-frac rounds that
fraction of the training batches' s to the nearest integer. Both are patched in for the run only:
the variants are not product options. Prints the all-mip PSNR, the sweep and its largest dip.
"""
from __future__ import annotations

import argparse
import math
from dataclasses import replace
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_lod_sweep as B  # noqa: E402
from common import specs  # noqa: E402

from bcfpipe.model import neural as M  # noqa: E402
from bcfpipe.train import trainer as T  # noqa: E402
from bcfpipe.config import PRESETS, ModelConfig, TrainConfig  # noqa: E402
from bcfpipe.export.material import train_material  # noqa: E402
from bcfpipe.texset.texture_set import load_texture_set  # noqa: E402
from bcfpipe.formats.vocabulary import FeatureFormat  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("name")
    ap.add_argument("--res", type=int, default=512)
    ap.add_argument("--rule", choices=("natural", "span"), default="span")
    ap.add_argument("--extra", default="0,0,0,0", help="per-layer lod offsets added to the rule's biases")
    ap.add_argument("--int-frac", type=float, default=0.0)
    ap.add_argument("--preset", default="standard")
    ap.add_argument("--steps-x", type=float, default=1.0, help="multiply every phase's step count")
    ap.add_argument("--step", type=float, default=0.125)
    ap.add_argument("--out", type=Path, default=Path("/tmp/bcf_ablate_lod"))
    a = ap.parse_args()
    torch.set_num_threads(1)
    ts = load_texture_set(specs("teapot"), a.res)
    r = a.res // 2
    mc = ModelConfig(features=FeatureFormat.BC6H, resolutions=(r, r // 2, r // 4, r // 8))

    rule = M.lod_biases if a.rule == "span" else (
        lambda res, w, h: tuple(math.log2(max(x / w, x / h)) for x in res))
    extra = [float(x) for x in a.extra.split(",")]
    M.lod_biases = lambda res, w, h: tuple(b + e for b, e in zip(rule(res, w, h), extra))

    base = T.StratifiedScale

    class Scale(base):
        def __init__(self, s_max, gen, strata=16):
            super().__init__(s_max, gen, strata)
            self.rng = np.random.default_rng(1)

        def __call__(self):
            s = super().__call__()
            return float(round(s)) if self.rng.random() < a.int_frac else s

    T.StratifiedScale = Scale
    pre = PRESETS[a.preset]
    if a.steps_x != 1.0:
        def longer(ph):  # same total decay over more steps
            return replace(ph, steps=int(ph.steps * a.steps_x), gamma_features=ph.gamma_features ** (1 / a.steps_x),
                           gamma_mlp=ph.gamma_mlp ** (1 / a.steps_x))
        pre = replace(pre, warmup=longer(pre.warmup), constrained=longer(pre.constrained), finetune=longer(pre.finetune))
    cfg = TrainConfig(model=mc, preset=pre, preset_name=a.preset, threads=1)
    out = a.out / a.name
    res, _ = train_material(ts, out, cfg)
    rows = B.sweep(out, ts, a.step)
    worst = max(B.dips(rows), key=lambda t: t[1])
    p = np.array([row[1] for row in rows])
    print(" ".join(f"{row[0]:.2f}:{row[1]:.2f}" for row in rows))
    print(f"{a.name}: biases {M.lod_biases(mc.resolutions, ts.width, ts.height)}; all-mip PSNR {res.metrics.psnr:.2f} dB; "
          f"mean over s {p.mean():.2f} dB; largest dip {worst[1]:.2f} dB at s = {worst[0]:.3f}; "
          f"train {res.train_seconds:.0f} s")


if __name__ == "__main__":
    main()
