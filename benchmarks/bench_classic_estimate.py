"""Issue 58: the layout's classic estimates against full encodes, per candidate and per mip.

For each set (the teapot, brick, wood and water bottle, at R = the set's side, the default profile's),
every classic candidate the default layout weighs (BC@R, its BC7 repacks, the BC7 quality set) is
estimated as `bcfpipe.layout.classic_fit.estimated` does it (a jittered sample of blocks,
`bcfpipe.layout.estimate`) and encoded in full (`classic_fit.measure`), with the shipping encoders
and presets. Prints, per candidate, the all-channel PSNR per mip of both and their largest
difference, and the seconds of each.

  python benchmarks/bench_classic_estimate.py [--sets teapot,brick,wood,bottle] [--quality standard]
      [--json out.json]

``--quality`` picks the encoder presets (`config.ENCODE_PRESETS`: quicktex BC1 at level 13 at draft).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_default_cost import SETS  # noqa: E402
from common import add_options, machine, write_json  # noqa: E402


def main() -> None:
    from bcfpipe.config import ENCODE_PRESETS
    from bcfpipe.layout.classic_fit import ClassicWork, estimated, measure
    from bcfpipe.layout.kinds import CLASSIC
    from bcfpipe.texset.chain import Reference
    from bcfpipe.texset.texture_set import TextureSpec, load_texture_set

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_options(ap, sets="teapot,brick,wood,bottle", quality="standard")
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    enc = ENCODE_PRESETS[a.quality]
    print(f"machine: {machine()}; encoders of --quality {a.quality}: {enc}", flush=True)
    rows = []
    for name in a.sets.split(","):
        ts = load_texture_set([TextureSpec.parse(s) for s in SETS[name]])
        r = max(ts.width, ts.height)
        work = ClassicWork(ts, r, Reference.of(ts), "repeat", CLASSIC, enc=enc)
        t = time.perf_counter()
        est = estimated(work, whole_bc=False)
        t_est = time.perf_counter() - t
        cands = [est.bc, *est.packed] + ([est.quality] if est.quality.part else [])
        for c in cands:
            t = time.perf_counter()
            full = measure(work, est, None if c.kind.name == "bc@r" else c)
            t_full = time.perf_counter() - t
            f = full.bc if c.kind.name == "bc@r" else next(p for p in (*full.packed, full.quality) if p.part == c.part)
            use = list(est.use)
            diff = [round(x - y, 3) for x, y in zip(c.psnr_per_mip, f.psnr_per_mip)]
            worst = max(abs(diff[k]) for k in use)
            row = {"set": name, "candidate": c.label, "estimated": [round(v, 3) for v in c.psnr_per_mip],
                   "full": [round(v, 3) for v in f.psnr_per_mip], "difference_db": diff, "largest_db": worst,
                   "sampled": round(est.sampled, 3), "estimate_seconds_all": round(t_est, 1),
                   "full_seconds": round(t_full, 1)}
            rows.append(row)
            print(f"{name:7s} {c.label:45s} largest |est - full| {worst:.3f} dB over mips {use[0]}-{use[-1]} "
                  f"(per mip {diff[:len(use)]}); full encode {t_full:.1f} s", flush=True)
        print(f"{name:7s} every estimate: {t_est:.1f} s, {est.sampled:.0%} of BC@R's texels", flush=True)
    write_json(a.json, rows=rows)


if __name__ == "__main__":
    main()
