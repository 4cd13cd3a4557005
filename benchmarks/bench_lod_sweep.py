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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, specs  # noqa: E402

from bcfpipe.bench.lod_sweep import LodGrid, exported_answer, mips_answer, sweep as sweep_answer  # noqa: E402
from bcfpipe.bench.lod_sweep import dips as _dips  # noqa: E402
from bcfpipe.export import writer as E  # noqa: E402
from bcfpipe.texset.reference import ReferencePyramid  # noqa: E402
from bcfpipe.texset.texture_set import load_texture_set  # noqa: E402


def sweep(folder: Path, ts, step: float = 0.25, points: int = 1 << 16, seed: int = 0):
    """[(s, BCf PSNR, trilinear-of-the-reference PSNR)] over the sweep."""
    ref = ReferencePyramid.from_texture_set(ts)
    wrap = E.load(folder).wrap
    grid = LodGrid(ref, wrap, [c.peak for c in ts.channels], step, points, seed)
    bcf = sweep_answer(grid, exported_answer(folder))
    tri = sweep_answer(grid, mips_answer([np.moveaxis(m.cpu().numpy(), 0, -1) for m in ref.mips], wrap))
    return list(zip(grid.s, bcf, tri))


def dips(rows, col: int = 1, exact: float = 100.0):
    return _dips([r[0] for r in rows], [r[col] for r in rows], exact)


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
        sources = specs("teapot")
    else:
        from bcfpipe.texset.texture_set import TextureSpec
        desc = json.loads((a.material / "material.json").read_text())
        sources = [TextureSpec.parse(s) for s in desc["sources"]]
    ts = load_texture_set(sources)
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
