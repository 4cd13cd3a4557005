"""Training throughput on the teapot set (2048^2, 6 channels, profile 1k): samples/s per phase and
batch size, where a step's time goes, and the per-tap decode optimisation measured before/after.

  python benchmarks/bench_train_throughput.py [--device cpu] [--steps 6]

Sections of one step: reference (bicubic target sampling), features (feature sampling incl. BC6H
emulation, forward + backward), mlp (forward + backward), optimiser (Adam + projection).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, teapot_specs  # noqa: E402

from bcfpipe import model as M  # noqa: E402
from bcfpipe.bc6h import emulate  # noqa: E402
from bcfpipe.bc6h.encode import encode_params  # noqa: E402
from bcfpipe.config import PROFILES, ModelConfig  # noqa: E402
from bcfpipe.decoder import mlp_raw  # noqa: E402
from bcfpipe.reference import ReferencePyramid, random_batch, sample_reference  # noqa: E402
from bcfpipe.texset import load_texture_set  # noqa: E402


def _sync(dev):
    if dev.type == "cuda":
        torch.cuda.synchronize()


def build_state(ts, mc, dev, gen):
    free = M.init_free(mc, gen, dev)
    blocks = []
    with torch.no_grad():
        for mips in free:
            layer = []
            for p in mips:
                e, idx, part = encode_params(M.endpoint_value(p, mc.signed).permute(1, 2, 0).cpu().numpy())
                layer.append({"endpoints": torch.as_tensor(e, dtype=torch.float32, device=dev).requires_grad_(True),
                              "x": (torch.as_tensor(idx, dtype=torch.float32, device=dev) / 7).requires_grad_(True),
                              "mask": emulate.partition_mask(part, device=dev), "partition": part})
            blocks.append(layer)
    levels = [[M.block_level_fn(blocks, mc, True)(i, k).detach() for k in range(n)] for i, n in enumerate(mc.mip_counts)]
    return free, blocks, levels


def time_steps(phase, state, mlp, ref, mc, biases, batch, steps, taps, dev, gen):
    free, blocks, levels = state
    if phase == "warmup":
        params, lvl, tap = [t for m in free for t in m], M.free_level_fn(free, mc.signed), M.free_tap_fn(free, mc.signed)
    elif phase == "constrained":
        params = [t for l in blocks for b in l for t in (b["endpoints"], b["x"])]
        lvl, tap = M.block_level_fn(blocks, mc), M.block_tap_fn(blocks, mc)
    else:
        params, lvl, tap = [], M.cached_level_fn(levels), None
    mlp_params = [mlp[k] for k in ("w1", "b1", "w2", "b2")]
    groups = ([{"params": params, "lr": 0.1}] if params else []) + [{"params": mlp_params, "lr": 1e-3}]
    opt = torch.optim.Adam(groups, fused=True)
    sections = dict(reference=0.0, features=0.0, mlp=0.0, optimiser=0.0)
    s_values = torch.linspace(0, ref.num_levels - 1, steps + 1).tolist()
    for step in range(steps + 1):  # step 0 warms caches and is not counted
        uv, _ = random_batch(batch, gen, dev, 0)
        s = s_values[step]
        t = [time.perf_counter()]
        target = sample_reference(ref, uv, s, mc.wrap)
        _sync(dev); t.append(time.perf_counter())
        if taps and tap is not None:
            feats = M.sample_features_taps(tap, M.level_sizes(mc), biases, uv, s, mc.wrap)
        else:
            feats = M.sample_features(lvl, mc.mip_counts, biases, uv, s, mc.wrap)
        _sync(dev); t.append(time.perf_counter())
        f = feats.detach().requires_grad_(bool(params))
        pred = mlp_raw(mlp, f) * mlp["out_scale"] + mlp["out_bias"]
        loss = torch.mean((pred - target) ** 2)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        _sync(dev); t.append(time.perf_counter())
        if params:
            feats.backward(f.grad)
        _sync(dev); t.append(time.perf_counter())
        opt.step()
        _sync(dev); t.append(time.perf_counter())
        if step:
            sections["reference"] += t[1] - t[0]
            sections["features"] += (t[2] - t[1]) + (t[4] - t[3])
            sections["mlp"] += t[3] - t[2]
            sections["optimiser"] += t[5] - t[4]
    total = sum(sections.values())
    return steps * batch / total, {k: v / total for k, v in sections.items()}, total / steps


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--batches", default="262144,16384")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    dev = torch.device(a.device)
    gen = torch.Generator().manual_seed(0)
    ts = load_texture_set(teapot_specs())
    mc = ModelConfig(resolutions=PROFILES["1k"])
    ref = ReferencePyramid.from_texture_set(ts, dev)
    biases = M.lod_biases(mc.resolutions, ts.width, ts.height)
    mlp = M.init_mlp(12, 16, ts.num_channels, gen, dev, torch.zeros(ts.num_channels))
    t0 = time.perf_counter()
    state = build_state(ts, mc, dev, gen)
    print(f"# Training throughput: teapot 2048^2 x 6, profile 1k  ({machine()}, {torch.get_num_threads()} threads)")
    print(f"(state set-up incl. BC6H encode of all layers: {time.perf_counter() - t0:.1f} s; "
          f"s swept uniformly over [0, {ref.num_levels - 1}])\n")
    print("| phase | batch | decode | samples/s | s/step | reference | features+BC | MLP | optimiser |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|")
    for batch in (int(b) for b in a.batches.split(",")):
        steps = max(2, a.steps if batch > 65536 else a.steps * 4)
        for phase in ("warmup", "constrained", "finetune"):
            modes = (False, True) if phase != "finetune" else (False,)
            for taps in modes:
                rate, frac, per = time_steps(phase, state, mlp, ref, mc, biases, batch, steps, taps, dev, gen)
                name = "per-tap" if taps else ("whole level" if phase != "finetune" else "cached")
                print(f"| {phase} | {batch} | {name} | {rate:,.0f} | {per:.3f} | " +
                      " | ".join(f"{100 * frac[k]:.0f}%" for k in ("reference", "features", "mlp", "optimiser")) + " |",
                      flush=True)


if __name__ == "__main__":
    main()
