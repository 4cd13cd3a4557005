"""Training throughput on the teapot set (2048^2, 6 channels, profile 1k): samples/s per phase and
batch size, where a step's time goes, and the per-tap decode optimisation measured before/after.
A last section measures the fused BC6H emulation (``emulate.decode_blocks``, one autograd node)
against the composed one (``fused=False``) in the same run: decode_blocks forward + backward on
65,536 blocks (T0 mip 0 of profile 1k) and constrained-phase steps, interleaved repetitions.

  python benchmarks/bench_train_throughput.py [--device cpu] [--steps 6] [--fused-compare-only]

Sections of one step: reference (bicubic target sampling), features (feature sampling incl. BC6H
emulation, forward + backward), mlp (forward + backward), optimiser (Adam + projection).
"""
from __future__ import annotations

import argparse
import contextlib
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, teapot_specs  # noqa: E402

from bcfpipe.model import neural as M  # noqa: E402
from bcfpipe.bc6h import emulate  # noqa: E402
from bcfpipe.bc6h.encode import encode_params  # noqa: E402
from bcfpipe.config import PROFILES, ModelConfig  # noqa: E402
from bcfpipe.model.decoder import mlp_raw  # noqa: E402
from bcfpipe.model.features import BlockParams, Layers, endpoint_value  # noqa: E402
from bcfpipe.texset.reference import ReferencePyramid, random_batch, sample_reference  # noqa: E402
from bcfpipe.texset.texture_set import load_texture_set  # noqa: E402
from bcfpipe.formats.vocabulary import FeatureFormat


def _sync(dev):
    if dev.type == "cuda":
        torch.cuda.synchronize()


def build_state(ts, mc, dev, gen):
    """Free features (noise), their BC6H blocks (bcfpipe's encoder at its default settings) and the
    blocks' quantization-aware decoded levels: the three phases' states, as `bcfpipe.model.features.Layers`."""
    free = Layers.of(M.init_free(mc, gen, dev))

    def encode(p, i, k):
        e, idx, part = encode_params(endpoint_value(p, mc.signed).permute(1, 2, 0).cpu().numpy())
        return BlockParams(torch.as_tensor(e, dtype=torch.float32, device=dev).requires_grad_(True),
                           (torch.as_tensor(idx, dtype=torch.float32, device=dev) / 7).requires_grad_(True),
                           emulate.partition_mask(part, device=dev), part)

    with torch.no_grad():
        blocks = free.map(encode)
    levels = [[M.block_level_fn(blocks, mc, True)(i, k).detach() for k in range(n)] for i, n in enumerate(mc.mip_counts)]
    return free, blocks, levels


def time_steps(phase, state, mlp, ref, mc, biases, batch, steps, taps, dev, gen):
    free, blocks, levels = state
    if phase == "warmup":
        params, lvl, tap = free.trained_levels(), M.free_level_fn(free, mc), M.free_tap_fn(free, mc)
    elif phase == "constrained":
        params = [t for b in blocks.trained_levels() for t in (b.endpoints, b.x)]
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


@contextlib.contextmanager
def composed_decode(enabled: bool):
    """Route ``emulate.decode_blocks`` (which bcfpipe.model calls) to the composed version."""
    orig = emulate.decode_blocks
    if enabled:
        emulate.decode_blocks = lambda *args, **kw: orig(*args, **{**kw, "fused": False})
    try:
        yield
    finally:
        emulate.decode_blocks = orig


def saved_bytes(fn) -> int:
    """Bytes of the distinct tensor storages autograd saves for backward while ``fn`` runs."""
    seen = {}

    def pack(t):
        st = t.untyped_storage()
        seen[st.data_ptr()] = st.nbytes()
        return t
    with torch.autograd.graph.saved_tensors_hooks(pack, lambda t: t):
        out = fn()
    del out
    return sum(seen.values())


def random_blocks(n, dev, gen):
    e = (torch.rand((n, 4, 3), generator=gen) * 64 - 0.5).to(dev).requires_grad_(True)
    x = torch.rand((n, 16), generator=gen).to(dev).requires_grad_(True)
    mask = (torch.rand((n, 16), generator=gen) < 0.5).to(dev)
    return e, x, mask, torch.randn((n, 16, 3), generator=gen).to(dev)


def fused_compare(state, mlp, ref, mc, biases, dev, gen, reps, steps, batches):
    """Before/after table: composed vs fused decode_blocks, interleaved (order alternating)."""
    e, x, mask, g = random_blocks(65536, dev, gen)
    variants = {"composed": False, "fused": True}

    def micro(fused):
        _sync(dev)
        t0 = time.perf_counter()
        out = emulate.decode_blocks(e, x, mask, fused=fused)
        out.backward(g)
        _sync(dev)
        e.grad = x.grad = None
        return time.perf_counter() - t0

    def micro_fwd(fused):
        _sync(dev)
        t0 = time.perf_counter()
        with torch.no_grad():
            emulate.decode_blocks(e, x, mask, fused=fused)
        _sync(dev)
        return time.perf_counter() - t0

    def interleave(fn, n):
        times = {k: [] for k in variants}
        for r in range(n):
            for k in (list(variants) if r % 2 == 0 else list(variants)[::-1]):
                times[k].append(fn(variants[k]))
        return {k: statistics.median(v) for k, v in times.items()}

    for k in variants:  # warm-up
        micro(variants[k]), micro_fwd(variants[k])
    rows = []
    fb = interleave(micro, reps)
    fw = interleave(micro_fwd, reps)
    mem = {k: saved_bytes(lambda: emulate.decode_blocks(e, x, mask, fused=variants[k])) / 2**20 for k in variants}
    rows.append(("decode_blocks fwd+bwd, 65,536 blocks", "ms", {k: 1e3 * v for k, v in fb.items()}, True))
    rows.append(("decode_blocks fwd only (no_grad), 65,536 blocks", "ms", {k: 1e3 * v for k, v in fw.items()}, True))
    rows.append(("decode_blocks saved for backward", "MiB", mem, True))

    def step(fused, batch):
        with composed_decode(not fused):
            rate, frac, _ = time_steps("constrained", state, mlp, ref, mc, biases, batch,
                                       steps if batch > 65536 else 4 * steps, False, dev, gen)
        return rate, frac["features"]
    for batch in batches:
        res = {k: [] for k in variants}
        for r in range(reps):
            for k in (list(variants) if r % 2 == 0 else list(variants)[::-1]):
                res[k].append(step(variants[k], batch))
        name = f"constrained step, batch {batch} ({int(batch ** 0.5)}²)"
        rows.append((name, "samples/s", {k: statistics.median(a for a, _ in v) for k, v in res.items()}, False))
        rows.append((f"{name}: features+BC share", "% of step",
                     {k: 100 * statistics.median(b for _, b in v) for k, v in res.items()}, None))

    print(f"\n## Fused vs composed BC6H emulation (medians of {reps} interleaved repetitions; constrained "
          f"phase: {steps} steps per repetition at batch > 65536, {4 * steps} below)\n")
    print("| measurement | unit | composed | fused | fused vs composed |")
    print("|---|---|---:|---:|---:|")
    for name, unit, v, lower_better in rows:
        c, f = v["composed"], v["fused"]
        num = f"{c:,.0f} | {f:,.0f}" if unit in ("samples/s", "% of step") else f"{c:,.1f} | {f:,.1f}"
        if lower_better is None:
            change = ""
        else:
            ratio = c / f if lower_better else f / c
            change = f"{ratio:.2f}× " + ("less memory" if unit == "MiB" else "speed-up")
        print(f"| {name} | {unit} | {num} | {change} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--batches", default="262144,16384")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--fused-compare-only", action="store_true",
                    help="run only the fused-vs-composed BC6H emulation section")
    ap.add_argument("--fused-reps", type=int, default=7, help="interleaved repetitions of that section")
    ap.add_argument("--fused-batches", default="16384,262144", help="batch sizes of that section")
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    dev = torch.device(a.device)
    gen = torch.Generator().manual_seed(0)
    ts = load_texture_set(teapot_specs())
    mc = ModelConfig(features=FeatureFormat.BC6H, resolutions=PROFILES["1k"])
    ref = ReferencePyramid.from_texture_set(ts, dev)
    biases = M.lod_biases(mc.resolutions, ts.width, ts.height)
    mlp = M.init_mlp(12, 16, ts.num_channels, gen, dev, torch.zeros(ts.num_channels))
    t0 = time.perf_counter()
    state = build_state(ts, mc, dev, gen)
    print(f"# Training throughput: teapot 2048^2 x 6, profile 1k  ({machine()}, {torch.get_num_threads()} threads)")
    print(f"(state set-up incl. BC6H encode of all layers: {time.perf_counter() - t0:.1f} s; "
          f"s swept uniformly over [0, {ref.num_levels - 1}])\n")
    if not a.fused_compare_only:
        phase_table(a, state, mlp, ref, mc, biases, dev, gen)
    fused_compare(state, mlp, ref, mc, biases, dev, gen, a.fused_reps, a.steps,
                  [int(b) for b in a.fused_batches.split(",")])


def phase_table(a, state, mlp, ref, mc, biases, dev, gen):
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
