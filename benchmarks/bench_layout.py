"""Issue 31: each material's layout chosen by measured rate-distortion against BC@R.

For one set at R = 1024 (`--profile 1k`): BC@R measured per channel, the probe trained on all
channels, every candidate layout (classic groups × profiles) with its figures and basis, the
choice, the model trained for it, and the final choice among measured layouts with its per-mip
margin against BC@R. Every figure is from exported files (DDS features and the fp16 decoder through
onnxruntime; the classic groups' blocks through quicktex's decoder). Run one process per set to use
two cores.

  python benchmarks/bench_layout.py --set teapot [--match-bc] [--kernel fused] [--json out.json]
  python benchmarks/bench_layout.py --set teapot --classic albedo --layout-profile 0.5k [--lod-power 8]

``--classic GROUPS`` measures one layout instead of running the rule: those groups (comma list, as
the tables name them) classic, a model on the other channels alone at ``--layout-profile``.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, mip_columns, psnr_cells, specs  # noqa: E402


def row(c, bc, mark="", match_bc=False):
    from bcfpipe.layout.choose import admissible

    why = admissible(c, bc, match_bc) or "ok"
    return f"| {mark}{c.label} | {c.basis} | {c.size_bytes / 2**20:.2f} | {psnr_cells(c.psnr_per_mip, c.psnr)} | {why} |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, set="teapot", profile="1k", preset="standard")
    ap.add_argument("--match-bc", action="store_true")
    ap.add_argument("--kernel", default="auto")
    ap.add_argument("--features", default="bc6h", help="the feature format of every neural candidate")
    ap.add_argument("--json", default=None)
    ap.add_argument("--classic", default=None, help="measure this one layout: these groups classic")
    ap.add_argument("--layout-profile", default="0.5k", help="with --classic: the neural part's profile")
    ap.add_argument("--lod-power", type=float, default=None,
                    help="with --classic: draw the neural part's lods as s_max * u**P (the presets' P is 2)")
    args = ap.parse_args()

    from bcfpipe.config import PROFILES, TrainingOptions
    from bcfpipe.formats.vocabulary import Layout
    from bcfpipe.layout.decide import decide_layout
    from bcfpipe.texset.texture_set import load_texture_set

    ts = load_texture_set(specs(args.set))
    r = PROFILES[args.profile][0]
    opts = TrainingOptions(profile=args.profile, preset=args.preset, device="cpu", seed=0, threads=1,
                           kernel=args.kernel, features=args.features, layout=Layout.AUTO, match_bc=args.match_bc)
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height}, --profile {args.profile} (R = {r}), "
          f"{args.preset}, --features {args.features}, --kernel {args.kernel}, 1 thread"
          f"{', --match-bc' if args.match_bc else ''}", flush=True)
    if args.classic is not None:
        return one_layout(ts, opts, r, args.classic.split(","), args.layout_profile, args.lod_power)
    t = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bcfpipe-layout-") as tmp:
        fit = decide_layout(ts, tmp, opts, r, log=lambda s: print("  " + s, flush=True))
    n = len(fit.decision.bc.mse_per_mip)
    head = "| layout | basis | MiB | " + mip_columns(n) + " | all mips | admissible |"
    sep = "|---|---|---:|" + "---:|" * (n + 1) + "---|"
    print("\nCandidates (the first choice is made here):\n\n" + head + "\n" + sep)
    bc = fit.first.bc
    for c in sorted(fit.first.candidates, key=lambda c: -c.psnr):
        print(row(c, bc, "→ " if c is fit.first.chosen else "", args.match_bc))
    print("\nMeasured layouts (the final choice):\n\n" + head + "\n" + sep)
    for c in fit.decision.candidates:
        print(row(c, bc, "→ " if c is fit.decision.chosen else "", args.match_bc))
    ch = fit.decision.chosen
    print(f"\nchosen: {ch.label}: {fit.decision.reason}")
    print("margin against BC@R per mip (dB): " + " ".join(f"{v:+.1f}" for v in ch.margins(bc)))
    print(f"training {fit.train_seconds:.0f} s (the probe {fit.probe.train_seconds:.0f} s), "
          f"{time.perf_counter() - t:.0f} s in all", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"set": args.set, "decision": fit.decision.to_json(),
                                               "first": fit.first.to_json(), "train_seconds": fit.train_seconds,
                                               "seconds": fit.seconds}, indent=1))


def one_layout(ts, opts, r, classic, profile, lod_power=None) -> None:
    """Measure one layout: ``classic`` groups as BC@R has them, a model on the rest at ``profile``."""
    from dataclasses import replace

    from bcfpipe.export.material import train_material, make_config
    from bcfpipe.layout import choose as C
    from bcfpipe.layout.classic import channel_errors, encode
    from bcfpipe.layout.kinds import subset
    from bcfpipe.texset.texture_set import build_mip_chain

    ref = build_mip_chain(ts.data)
    use = tuple(k for k, m in enumerate(ref) if min(m.shape[:2]) >= 4)
    enc = encode(ts, r, ref)
    unknown = set(classic) - {g.group.name for g in enc}
    if unknown:
        raise SystemExit(f"no group {', '.join(sorted(unknown))}; the set has {', '.join(g.group.name for g in enc)}")
    e_bc = channel_errors(ts, enc, ref)
    bc = C.Candidate(tuple(g.group.name for g in enc), None, sum(g.size_bytes for g in enc),
                     C.combine(None, e_bc, range(ts.num_channels)), "measured", use)
    keep = [c for c in range(ts.num_channels) if not any(c in g.group.channels for g in enc if g.group.name in classic)]
    sub = subset(ts, keep)
    with tempfile.TemporaryDirectory(prefix="bcfpipe-layout-") as tmp:
        cfg = make_config(sub, replace(opts, profile=profile))[1]
        if lod_power is not None:
            cfg = replace(cfg, preset=replace(cfg.preset, lod_power=lod_power))
        res, _ = train_material(sub, Path(tmp) / "m", cfg, profile)
    e = e_bc.copy()
    e[:, keep] = res.mse_per_channel
    c = C.Candidate(tuple(classic), profile, res.size_bytes + sum(g.size_bytes for g in enc if g.group.name in classic),
                    tuple(float(v) for v in e.mean(1)), "measured", use)
    n = len(ref)
    print("\n| layout | basis | MiB | " + mip_columns(n) + " | all mips | admissible |")
    print("|---|---|---:|" + "---:|" * (n + 1) + "---|")
    print(row(bc, bc))
    print(row(c, bc))
    print(f"\nthe neural part alone ({len(keep)} channels at {profile}): "
          + " ".join(f"{v:.1f}" for v in res.metrics.psnr_per_mip) + f"; trained in {res.train_seconds:.0f} s")


if __name__ == "__main__":
    main()
