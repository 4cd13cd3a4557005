"""Issue 29: what every BC7 mode would buy trained features, before building a trainer for them.

`--features bc7` trains mode 6 only (one subset, RGBA, 4-bit indices): the mode a differentiable
emulation follows exactly. The PCA oracle (bound_t0.py) says ISPC's free choice of mode holds 3.5 dB
more of the brick at mip 1 than mode 6 does. Whether trained features would gain the same is
measured here, in process (exact decoded levels, the float MLP; no export), from one warm-up:

* ``pipeline``: the preset as it ships: warm-up, mode-6 encode, constrained phase, quantize, MLP
  fine-tune (bcfpipe.train.trainer.train, unchanged);
* ``free + mode 6``: warm-up for the same total steps (free features), bcfpipe's mode-6 encode,
  MLP fine-tune on the decoded levels;
* ``free + ISPC``: the same warm features, ISPC's BC7 (every mode, `baselines.BC7_SETTINGS`),
  decoded by texture2ddecoder, the same MLP fine-tune from the same MLP.

* ``ISPC in the loop``: the preset's warm-up, then for the constrained phase's steps the free
  features trained straight through ISPC's blocks: every step decodes the features as ISPC encoded
  them (free + an offset, refreshed by encoding them again every ``--refresh`` steps) and applies
  the gradient to the free features; then ISPC's blocks of the final features, and the fine-tune.

The second and third differ only in the encoder, so their gap is what the modes buy trained features
without a constrained phase; the first row is what the constrained phase buys mode 6, the last what
a straight-through phase buys every mode.

  python benchmarks/bound_bc7_modes_trained.py --set brick [--profile 1k] [--finetune 300]
"""
from __future__ import annotations

import argparse
import copy
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, mip_columns, psnr_cells, specs  # noqa: E402


def psnr_row(mse: np.ndarray, ts) -> tuple[list[float], float]:
    """Per-mip and all-mip PSNR of (mips, channels) errors, as bcfpipe.texset.metrics weighs them."""
    peaks = np.array([ch.peak ** 2 for ch in ts.channels])
    per = (mse / peaks).mean(1)
    use = [k for k in range(len(per)) if (ts.width >> k) >= 4 and (ts.height >> k) >= 4]
    return [float(-10 * np.log10(v)) for v in per], float(-10 * np.log10(per[use].mean()))


class _StraightThrough:
    """The fused step over free features, each step run at free + offset (the offset: ISPC's decoded
    blocks minus the free features, refreshed every ``every`` steps), the gradient kept for the free
    features: straight through the encoder."""

    def __init__(self, fused, params, offsets_of, every: int):
        self.fused, self.params, self.offsets_of, self.every = fused, params, offsets_of, every
        self.owns_adam, self.step, self.offsets, self.encodes = fused.owns_adam, 0, None, 0.0

    def __call__(self, uv, target, weight, s):
        import torch

        if self.step % self.every == 0:
            t0 = time.perf_counter()
            self.offsets = self.offsets_of()
            self.encodes += time.perf_counter() - t0
        self.step += 1
        with torch.no_grad():
            for p, o in zip(self.params, self.offsets):
                p.add_(o)
        loss = self.fused(uv, target, weight, s)
        with torch.no_grad():
            for p, o in zip(self.params, self.offsets):
                p.sub_(o)
        return loss

    def adam(self, lr: float) -> None:
        self.fused.adam(lr)


def _flat(layers):
    return [t for mips in layers for t in mips]


def ste(ts, cfg, keep, ispc_levels, every, T, M, codec_of):
    """The ``ISPC in the loop`` row: (label, (mips, channels) MSE, seconds)."""
    import torch

    warm = T._warmup

    def warm_then_ste(run):
        free = warm(run)
        mc = run.cfg.model
        codec = codec_of(mc)
        lo, hi = codec.param_range(mc)
        fused = run.backend.free_step(free)
        params = free.trained_levels()

        def offsets():
            dec = ispc_levels(run, free)
            return [d.mul(255.0).sub_(p.detach().clamp(lo, hi)) for d, p in zip(_flat(dec), params)]

        st = _StraightThrough(fused, params, offsets, every)

        def project():
            for t in params:
                t.clamp_(lo, hi)

        T._run_phase(run, "constrained", st, params, T._scaled(run.cfg.preset.constrained, codec, "constrained"),
                     project=project)
        keep.update(ispc=ispc_levels(run, free), encodes=st.encodes)
        return free

    encode, quantize, constrained = T._encode, T._quantize, T._constrained

    def quantize_ispc(run, blocks):
        layers, _ = quantize(run, blocks)
        keep["run"] = run
        return layers, keep["ispc"]

    T._warmup, T._quantize, T._constrained = warm_then_ste, quantize_ispc, lambda run, blocks: None
    t0 = time.perf_counter()
    try:
        T.train(ts, cfg, measure_float=False)
    finally:
        T._warmup, T._encode, T._quantize, T._constrained = warm, encode, quantize, constrained
    run = keep["run"]
    mse = T.float_model_mse(M.cached_level_fn(keep["ispc"]), run.mlp, cfg.model, tuple(c.kind for c in ts.channels),
                            run.biases, run.ref)
    print(f"ISPC in the loop: {keep['encodes']:.0f} s of encodes every {every} steps")
    return f"ISPC in the loop (every {every} steps)", mse, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, set="brick", profile="1k", preset="standard")
    ap.add_argument("--finetune", type=int, default=0, help="MLP fine-tune steps of the free rows (0: the preset's)")
    ap.add_argument("--skip-pipeline", action="store_true")
    ap.add_argument("--refresh", type=int, default=500, help="steps between ISPC encodes in the loop")
    ap.add_argument("--skip-ste", action="store_true")
    args = ap.parse_args()

    import torch

    from bcfpipe.config import TrainingOptions
    from bcfpipe.export.material import make_config
    from bcfpipe.model import neural as M
    from bcfpipe.model.features import codec_of
    from bcfpipe.texset.baselines import bc7_mips
    from bcfpipe.texset.texture_set import load_texture_set
    from bcfpipe.train import trainer as T

    ts = load_texture_set(specs(args.set))
    opts = TrainingOptions(profile=args.profile, preset=args.preset, device="cpu", seed=0, threads=1, features="bc7",
                           t0="trained")  # every layer trained from noise, as when this was measured (no fixed T_0)
    _, cfg = make_config(ts, opts)
    p = cfg.preset
    print(f"machine: {machine()}; {args.set}, {args.profile}, {args.preset}, bc7: warm-up {p.warmup.steps} + "
          f"constrained {p.constrained.steps} + fine-tune {p.finetune.steps} steps of {p.batch}")
    rows = []
    if not args.skip_pipeline:
        keep = {}
        quantize = T._quantize

        def grab(run, blocks):
            layers, exact = quantize(run, blocks)
            keep.update(run=run, exact=exact)
            return layers, exact

        T._quantize = grab
        t0 = time.perf_counter()
        T.train(ts, cfg, measure_float=False)
        T._quantize = quantize
        run = keep["run"]
        rows.append(("pipeline (mode 6, constrained phase)", T.float_model_mse(
            M.cached_level_fn(keep["exact"]), run.mlp, cfg.model, tuple(c.kind for c in ts.channels), run.biases,
            run.ref), time.perf_counter() - t0))

    steps = p.warmup.steps + p.constrained.steps
    fine = replace(p.finetune, steps=args.finetune or p.finetune.steps)
    free_cfg = cfg.with_(preset=replace(p, warmup=replace(p.warmup, steps=steps),
                                        constrained=replace(p.constrained, steps=0), finetune=fine))
    keep = {}
    encode, quantize = T._encode, T._quantize

    def ispc_levels(run, free):
        """ISPC's decoded levels of the free features, (C, H, W) texel values per level."""
        mc = run.cfg.model
        codec = codec_of(mc)
        lo, hi = codec.param_range(mc)
        out = []
        with torch.no_grad():
            for mips in free:
                levels = [codec.value(q.clamp(lo, hi), mc).permute(1, 2, 0).cpu().numpy() for q in mips]
                dec, _ = bc7_mips(levels)
                out.append([torch.from_numpy(np.ascontiguousarray(d.transpose(2, 0, 1))) for d in dec])
        return out

    def encode_both(run, free):
        keep["ispc"] = ispc_levels(run, free)
        return encode(run, free)

    def quantize_both(run, blocks):
        layers, exact = quantize(run, blocks)
        keep.update(run=run, exact6=exact, mlp0=copy.deepcopy({k: v.detach().clone() for k, v in run.mlp.items()}))
        return layers, keep["ispc"]  # phase 4 fine-tunes on ISPC's levels

    T._encode, T._quantize = encode_both, quantize_both
    t0 = time.perf_counter()
    T.train(ts, free_cfg, measure_float=False)
    T._encode, T._quantize = encode, quantize
    run = keep["run"]
    kinds = tuple(c.kind for c in ts.channels)
    t_ispc = time.perf_counter() - t0
    rows.append(("free + ISPC (every mode)", T.float_model_mse(M.cached_level_fn(keep["ispc"]), run.mlp, cfg.model,
                                                              kinds, run.biases, run.ref), t_ispc))
    with torch.no_grad():  # the same warm MLP, fine-tuned on the mode-6 levels instead
        for k, v in keep["mlp0"].items():
            run.mlp[k].copy_(v)
    t0 = time.perf_counter()
    T._run_phase(run, "finetune", run.backend.cached_step(keep["exact6"]), [], fine)
    rows.append(("free + mode 6 (bcfpipe's encoder)", T.float_model_mse(
        M.cached_level_fn(keep["exact6"]), run.mlp, cfg.model, kinds, run.biases, run.ref), time.perf_counter() - t0))

    if not args.skip_ste:
        keep.clear()
        rows.append(ste(ts, cfg, keep, ispc_levels, args.refresh, T, M, codec_of))

    n = len(rows[0][1])
    print("\n| features | " + mip_columns(n) + " | all mips | time |")
    print("|---|" + "---:|" * (n + 2))
    for label, mse, sec in rows:
        per, allm = psnr_row(mse, ts)
        print(f"| {label} | {psnr_cells(per, allm)} | {sec:.0f} s |")


if __name__ == "__main__":
    main()
