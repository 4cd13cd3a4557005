"""Issue 58: the layout's probe measured on a sample of its texels, against every texel.

For each named set, the probe the default layout trains at draft (all channels at its p0, 15 % of
the steps, `layout.decide._train_probe`'s config) is trained once; its exported files are measured
on every texel, on the sample the probe takes now (`export.material.sampled_texels`: one texel per
4×4 cell of a mip whose quarter is over 2^18 texels, per 2×2 cell of one over 2^18) and on the one it
took before (per 2×2 cell of a mip over 2^20). Prints per mip the PSNR over all channels of each,
the largest per-channel gap to every texel (and over the channels
below 40 dB, where a floor can bind), and the seconds each measure took (the decode included).

  python benchmarks/bench_probe_sample.py [--sets teapot,brick,wood,bottle]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_default_cost import SETS  # noqa: E402
from common import machine  # noqa: E402

RULES = {"now": None, "before": (1 << 20, None), "every texel": "all"}


def probe_folder(name: str, out: Path):
    """The set, its reference, and the folder of the probe the default layout trains at draft."""
    from bcfpipe.config import TrainingOptions, shortened
    from bcfpipe.export.material import FIGURES, make_config, train_material
    from bcfpipe.layout import decide
    from bcfpipe.layout.kinds import capped
    from bcfpipe.texset.chain import Reference
    from bcfpipe.texset.texture_set import load_texture_set

    ts = load_texture_set(SETS[name])
    options = TrainingOptions(preset="draft")
    asked, cfg = make_config(ts, options, "repeat")
    pred = decide.predict_for(ts, options, cfg, asked, max(ts.width, ts.height))
    own = pred.probe if pred.probe in {"tiny", "0.5k", "1k", "2k", "4k"} else options.profile
    probe = make_config(ts, replace(options, profile=own, t0_layers=pred.probe_t0_layers), "repeat")[1]
    probe = capped(probe, cfg.preset)
    probe = probe.with_(preset=shortened(probe.preset, decide.PROBE_FRACTION), t0_bc7=decide.PROBE_T0_BC7)
    ref = Reference.of(ts, None, "repeat")
    res = train_material(ts, out, probe, pred.probe, measure=FIGURES, reference=ref)[0]
    return ts, ref, res.out_dir


def measured(folder, ref, ts, rule):
    """(per-channel MSE per mip, seconds) of ``folder`` under a sampling ``rule``."""
    from bcfpipe.export import material as M

    saved = M.SAMPLED_TEXELS, M.SAMPLED_MOST
    if isinstance(rule, tuple):
        M.SAMPLED_TEXELS, M.SAMPLED_MOST = rule
    try:
        t = time.perf_counter()
        ev = M.evaluate_exported(folder, ref, ts.channels, image_metrics=False, sampled=rule != "all")
        return ev.per_channel, time.perf_counter() - t
    finally:
        M.SAMPLED_TEXELS, M.SAMPLED_MOST = saved


def main() -> None:
    from bcfpipe.texset.metrics import psnr_from_mse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", default="teapot,brick,wood,bottle")
    a = ap.parse_args()
    print(f"machine: {machine()}", flush=True)
    for name in a.sets.split(","):
        with tempfile.TemporaryDirectory() as tmp:
            ts, ref, folder = probe_folder(name, Path(tmp) / "probe")
            found = {label: measured(folder, ref, ts, rule) for label, rule in RULES.items()}
        every = found["every texel"][0]
        for label in ("now", "before"):
            e, s = found[label]
            over_all = [psnr_from_mse(float(m.mean())) - psnr_from_mse(float(w.mean())) for m, w in zip(e, every)]
            per_channel = np.abs(10 * np.log10(np.maximum(every, 1e-12) / np.maximum(e, 1e-12)))
            k, c = np.unravel_index(int(np.argmax(per_channel)), per_channel.shape)
            low = np.array([[psnr_from_mse(float(x)) < 40 for x in row] for row in every])
            gap_low = float(per_channel[low].max()) if low.any() else 0.0
            print(f"{name:7s} {label:7s}: {s:5.2f} s (every texel {found['every texel'][1]:.2f} s); PSNR gap to every "
                  f"texel per mip, all channels: {' '.join(f'{g:+.3f}' for g in over_all)} dB; largest per channel "
                  f"{per_channel.max():.3f} dB (mip {k}, {ts.channels[c].name} at {psnr_from_mse(float(every[k, c])):.1f} dB)"
                  f"; over channels below 40 dB {gap_low:.3f} dB", flush=True)


if __name__ == "__main__":
    main()
