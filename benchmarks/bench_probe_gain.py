"""Issue 58: what a full training at the asked preset gains over the layout's probe, per mip.

The default layout's probe (`bcfpipe.layout.decide._train_probe`) trains the set's model at p0 for
`PROBE_FRACTION` of the steps; the candidate it stands for, trained in full, holds more. For each
set this trains both, the same model (all channels, p0, T_0 width w0) with the same reference
chain, and prints each one's per-mip PSNR from its exported files and the difference: the table
`bcfpipe.train.gains.PROBE_GAINS_DB` holds, by T_0's place (the mips finer than T_0, T_0's level 0,
every coarser mip).

  python benchmarks/bench_probe_gain.py [--sets teapot,brick,wood,bottle] [--quality draft] [--json out.json]
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
from common import add_options, machine, write_json  # noqa: E402


def per_mip_psnr(mse: np.ndarray) -> list[float]:
    from bcfpipe.texset.metrics import psnr_from_mse

    return [round(psnr_from_mse(float(m)), 3) for m in mse.mean(1)]


def table_row(rows: list[dict]) -> tuple[float, ...]:
    """The mean gain over the sets by T_0's place: finer than its level 0, at it, one finer... as
    `bcfpipe.train.gains.probe_gains` reads it; the mips averaged are those the layout weighs (a
    smaller side of at least 4 texels, `choose`)."""
    cls: list[list[float]] = [[], [], [], []]
    for r in rows:
        t0, g = r["t0_mip"], r["gain_db"]
        use = [k for k in range(len(g)) if r["side"] >> k >= 4]
        per = [[g[k] for k in use if k < t0], [g[t0]], [g[t0 + 1]], [g[k] for k in use if k > t0 + 1]]
        for c, v in zip(cls, per):
            if v:
                c.append(sum(v) / len(v))
    return tuple(round(sum(c) / len(c), 2) if c else 0.0 for c in cls)


def main() -> None:
    from bcfpipe.config import PROFILES, TrainingOptions, shortened
    from bcfpipe.export.material import FIGURES, PROBE, evaluate_exported, train_material, make_config
    from bcfpipe.layout.decide import PROBE_FRACTION, predict_for
    from bcfpipe.layout.kinds import capped
    from bcfpipe.layout.predict import bc_resolution
    from bcfpipe.texset.chain import Reference
    from bcfpipe.texset.texture_set import TextureSpec, load_texture_set

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_options(ap, sets="teapot,brick,wood,bottle", quality="draft")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    print(f"machine: {machine()}; quality {a.quality}; probe {PROBE_FRACTION:.0%} of the steps", flush=True)
    rows = []
    for name in a.sets.split(","):
        ts = load_texture_set([TextureSpec.parse(s) for s in SETS[name]])
        options = TrainingOptions(preset=a.quality)
        asked, cfg = make_config(ts, options)
        pred = predict_for(ts, options, cfg, asked, bc_resolution(max(ts.width, ts.height), options.profile))
        p0, w0 = pred.probe, pred.probe_t0_layers
        if p0 is None:
            print(f"{name}: no probe (nothing neural fits within BC@R's bytes)", flush=True)
            continue
        own = p0 if p0 in PROFILES else options.profile
        full = capped(make_config(ts, replace(options, profile=own, t0_layers=w0))[1], cfg.preset)
        probe = full.with_(preset=shortened(full.preset, PROBE_FRACTION))
        ref = Reference.of(ts, None, "repeat")
        out = {}
        with tempfile.TemporaryDirectory() as tmp:
            for label, c in (("probe", probe), ("full", full)):
                t = time.perf_counter()
                res = train_material(ts, Path(tmp) / label, c, p0, measure=PROBE if label == "probe" else FIGURES,
                                   reference=ref)[0]  # each as the layout measures it
                out[label] = (per_mip_psnr(res.mse_per_channel), time.perf_counter() - t)
                if label == "probe":  # the sampled measure against every texel's
                    whole = evaluate_exported(res.out_dir, ref, ts.channels, image_metrics=False).per_channel
                    out["sampling"] = [round(x - y, 3) for x, y in zip(out["probe"][0], per_mip_psnr(whole))]
        t0 = res.resolutions[0]
        t0_mip = max(0, (max(ts.width, ts.height) // t0).bit_length() - 1)
        gain = [round(f - p, 3) for f, p in zip(out["full"][0], out["probe"][0])]
        row = {"set": name, "quality": a.quality, "side": min(ts.width, ts.height), "p0": p0, "t0_layers": w0, "t0_mip": t0_mip,
               "probe_psnr": out["probe"][0], "full_psnr": out["full"][0], "gain_db": gain,
               "probe_seconds": round(out["probe"][1], 1), "full_seconds": round(out["full"][1], 1),
               "sampled_minus_whole_db": out["sampling"]}
        rows.append(row)
        print(f"{name:7s} p0 {p0} (T_0 level 0 serves mip {t0_mip}): probe {out['probe'][1]:.1f} s, "
              f"full {out['full'][1]:.1f} s; gain per mip {gain}; the probe's sampled measure minus its "
              f"whole one {out['sampling']}", flush=True)
    if rows:
        print(f"PROBE_GAINS_DB[{a.quality!r}] = {table_row(rows)}  (mean over the sets: finer than T_0, "
              "T_0's level 0, its level 1, every coarser mip whose smaller side is at least 4)", flush=True)
    write_json(a.json, indent=1, rows=rows)


if __name__ == "__main__":
    main()
