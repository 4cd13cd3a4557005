"""PSNR of an exported material as a function of the lod s (the paper's learnfilter figure).

For each s the reference is F(M)(u, v, s): bicubic in mips floor(s), floor(s)+1 lerped by frac(s),
exactly the training target; the model is the exported BC6H DDS + fp16 decoder through
onnxruntime. Points are one fixed set of uniformly random uv (the same for every s, so the curve
measures only the change of scale; a texel-centre grid that changes at integer s would add a
saw-tooth of its own). A dip at s is how far the value lies below the mean of its two neighbours.

Criterion (issue #9): s from 0 to max in steps of 0.25 (``--step``); at every s, BCf's dip may be at
most 0.5 dB deeper than the trilinear reference's dip at the same s, both from this one run.

For scale, the same sweep is run on the classic answer to the same query: the hardware trilinear
filter over the reference's own mip chain ("trilinear ref", what an uncompressed mipmapped texture
gives at 1 spp). Any trilinear-filtered model shares its structure: between integer s the errors
of two mips are averaged, so PSNR peaks between integers and is lowest at them.

  python benchmarks/bench_lod_sweep.py OUT_MATERIAL_DIR [--png docs/lod_sweep.png]
(the texture set is rebuilt from material.json's sources; pass --teapot for the teapot set)
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, teapot_specs  # noqa: E402

from bcfpipe.export import writer as E  # noqa: E402
from bcfpipe.model.decoder import ONNX_INPUT, ONNX_OUTPUT, normal_xy_index  # noqa: E402
from bcfpipe.texset.reference import ReferencePyramid, sample_reference  # noqa: E402
from bcfpipe.model.sampling import sample_trilinear  # noqa: E402
from bcfpipe.texset.texture_set import load_texture_set  # noqa: E402


def sweep(folder: Path, ts, step: float = 0.25, points: int = 1 << 16, seed: int = 0):
    em = E.load(folder)
    ref = ReferencePyramid.from_texture_set(ts)
    s_max = ref.num_levels - 1
    sess = E.onnx_session(em)
    nz = normal_xy_index(em.kinds)
    peaks = np.array([c.peak for c in ts.channels], np.float32)
    rng = np.random.default_rng(seed)
    uv = rng.random((points, 2), dtype=np.float32)
    rows = []
    for s in np.linspace(0, s_max, int(round(s_max / step)) + 1):
        target = sample_reference(ref, torch.from_numpy(uv), float(s), em.wrap).numpy()
        y = sess.run([ONNX_OUTPUT], {ONNX_INPUT: E.sample_exported_features(em, uv, float(s))})[0]
        if nz is not None:
            y = np.delete(y, nz + 2, axis=1)
        mse = float(np.mean(((y - target) / peaks) ** 2))
        tri = sample_trilinear(ref.mips, torch.from_numpy(uv), float(s), em.wrap).numpy()
        mse_tri = float(np.mean(((tri - target) / peaks) ** 2))
        rows.append((float(s), 10 * np.log10(1 / mse), 10 * np.log10(1 / mse_tri)))
    return rows


def dips(rows, col: int = 1, exact: float = 100.0):
    """(s, dB below the mean of the two neighbouring values) for every inner value of s. Triples
    touching a value above ``exact`` dB are left out (the trilinear reference is exact at the 1x1
    mip, where its PSNR is only limited by float rounding)."""
    p = [r[col] for r in rows]
    return [(rows[i][0], (p[i - 1] + p[i + 1]) / 2 - p[i]) for i in range(1, len(p) - 1)
            if max(p[i - 1], p[i], p[i + 1]) < exact]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("material", type=Path)
    ap.add_argument("--teapot", action="store_true", help="the reference is the teapot set (6 channels)")
    ap.add_argument("--step", type=float, default=0.25, help="sweep step in s (issue #9: 0.25)")
    ap.add_argument("--limit", type=float, default=0.5, help="largest allowed excess of BCf's dip over trilinear's (dB)")
    ap.add_argument("--png", type=Path)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    if a.teapot:
        specs = teapot_specs()
    else:
        from bcfpipe.texset.texture_set import TextureSpec
        desc = json.loads((a.material / "material.json").read_text())
        specs = [TextureSpec.parse(s) for s in desc["sources"]]
    ts = load_texture_set(specs)
    rows = sweep(a.material, ts, a.step)
    worst = max(dips(rows), key=lambda t: t[1])
    worst_tri = max(dips(rows, 2), key=lambda t: t[1])
    tri_dip = dict(dips(rows, 2))
    excess = [(s_, d - tri_dip[s_]) for s_, d in dips(rows) if s_ in tri_dip]
    worst_x = max(excess, key=lambda t: t[1])
    p = np.array([r[1] for r in rows])
    print(f"# PSNR over lod: {a.material}  ({machine()})")
    bdip = dict(dips(rows))
    print("| s | BCf PSNR (dB) | trilinear ref PSNR (dB) | BCf dip | trilinear dip | excess |\n|---:|---:|---:|---:|---:|---:|")
    for s, pm, pt in rows:
        d, t = bdip.get(s), tri_dip.get(s)
        cells = [f"{d:+.2f}" if d is not None else "", f"{t:+.2f}" if t is not None else "",
                 f"{d - t:+.2f}" if d is not None and t is not None else ""]
        print(f"| {s:.2f} | {pm:.2f} | {pt:.2f} | " + " | ".join(cells) + " |")
    print(f"\nBCf: min {p.min():.2f} dB at s = {rows[int(p.argmin())][0]:.3f}, mean {p.mean():.2f} dB; largest dip "
          f"below the neighbours' mean: {worst[1]:.2f} dB at s = {worst[0]:.2f}")
    print(f"trilinear ref: largest dip below the neighbours' mean: {worst_tri[1]:.2f} dB at s = {worst_tri[0]:.2f}")
    print(f"largest excess of BCf's dip over trilinear's at the same s: {worst_x[1]:.2f} dB at s = {worst_x[0]:.2f} "
          f"({'PASS' if worst_x[1] <= a.limit else 'FAIL'}: limit {a.limit} dB, step {a.step})")
    if a.json:
        a.json.write_text(json.dumps({"rows": rows, "worst_dip_db": worst[1], "worst_dip_s": worst[0],
                                      "trilinear_worst_dip_db": worst_tri[1], "worst_excess_db": worst_x[1],
                                      "worst_excess_s": worst_x[0]}, indent=1))
    if a.png:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(7, 3.2), dpi=120)
        ax.plot([r[0] for r in rows], [r[1] for r in rows], "o-", ms=3, label="BCf (exported BC6H + fp16 decoder)")
        tri = [(r[0], r[2]) for r in rows if r[2] < 100]  # the 1x1 mip is exact for trilinear
        ax.plot([t[0] for t in tri], [t[1] for t in tri], "s--", ms=2, lw=1, color="0.5",
                label="trilinear over the reference's own mips")
        ax.set_ylim(min(min(r[1], r[2]) for r in rows) - 1, 56)
        ax.legend(fontsize=7, loc="lower right")
        ax.set_xlabel("lod s (reference mip units)")
        ax.set_ylabel("PSNR (dB)")
        ax.set_title(f"{a.material.name}: PSNR over lod against the bicubic-lerp target")
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(a.png)
        print(f"wrote {a.png}")


if __name__ == "__main__":
    main()
