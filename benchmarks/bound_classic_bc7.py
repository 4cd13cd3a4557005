"""Issue 31: classic groups repacked as BC7 at equal bytes, against BC@R, per mip. An oracle: no
training, every figure from encoded and decoded blocks.

BC@R ships a colour (or packed) group as BC1 (4 bits per texel) and a lone scalar as BC4 (4 bits
per texel). One BC7 RGBA texture (8 bits per texel) holds both in the same bytes, with 4-bit
indices, 7-bit endpoints and partitions, and the alpha channel either shared with the colour
(modes 6, 7) or separate (modes 4, 5). Each candidate below merges one BC1 group with one BC4
group into BC7 (ISPC, `bcfpipe.texset.baselines.BC7_SETTINGS`; texture2ddecoder decodes), the
other groups as BC@R has them; "all BC7" packs every channel, four per texture, where that fits
BC@R's bytes.

Sets: ``teapot``, ``brick`` and ``wood`` (held out: MaterialX's wood colour and roughness) at R =
1024 over every texel, and ``sample:NAME``: a texture set of
samples/sample_scene.usda as a build with no option settles it (R = its source side, over the
texels the meshes read).

  python benchmarks/bound_classic_bc7.py [--sets teapot,brick,wood,sample:Bricks,sample:Tiles,sample:Leaves]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, machine, mip_columns, psnr_cells, specs  # noqa: E402


def load(name: str):
    """(texture set, R, level-0 coverage mask or None, addressing)."""
    from bcfpipe.texset.texture_set import TextureSpec, load_texture_set

    if not name.startswith("sample:"):  # wood: held out, a colour and a lone scalar (BC1 + BC4 in BC@R)
        return load_texture_set(specs(name)), 1024, None, "repeat"
    from bcfpipe.builder.plan import plan
    from bcfpipe.scan.coverage import unpack

    bp = plan(REPO / "samples" / "sample_scene.usda")
    job = bp.job(name.split(":", 1)[1])
    ts = load_texture_set([TextureSpec(sem, path, ch) for sem, path, ch in job.specs])
    mask = unpack(job.coverage, ts.width, ts.height) if job.coverage is not None else None
    return ts, max(ts.width, ts.height), mask, job.wrap


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="teapot,brick,wood,sample:Bricks,sample:Tiles,sample:Leaves")
    args = ap.parse_args()

    from bcfpipe.layout import choose as C
    from bcfpipe.layout.classic import channel_errors, encode, measure_repack, repacks
    from bcfpipe.scan.coverage import mask_mips
    from bcfpipe.texset.texture_set import build_mip_chain

    print(f"machine: {machine()}")
    for name in args.sets.split(","):
        t0 = time.perf_counter()
        ts, r, mask, wrap = load(name)
        ref = build_mip_chain(ts.data)
        use = tuple(k for k, m in enumerate(ref) if min(m.shape[:2]) >= 4)
        masks = mask_mips(mask, len(ref), wrap) if mask is not None else None
        groups = encode(ts, r, ref, wrap)
        e_bc = channel_errors(ts, groups, ref, masks)
        bc = C.Candidate(tuple(g.group.name for g in groups), None, sum(g.size_bytes for g in groups),
                         C.combine(None, e_bc, range(ts.num_channels)), "measured", use)
        rows = [("BC@R: " + ", ".join(f"{g.group.name} {g.group.format.upper()}" for g in groups), bc)]
        for rp in repacks([g.group for g in groups]):
            _, e, size = measure_repack(ts, groups, e_bc, rp, r, ref, masks, wrap)
            rows.append((rp.label, C.Candidate((), None, size, tuple(float(v) for v in e.mean(1)), "measured", use)))
        print(f"\n### {name} (R = {r}, {ts.num_channels} channels{', over the texels read' if mask is not None else ''};"
              f" {time.perf_counter() - t0:.0f} s)\n")
        print(f"| layout | bytes | {mip_columns(use)} | all mips | worst margin |")
        print("|---|---:|" + "---:|" * len(use) + "---:|---:|")
        for label, c in rows:
            worst = min(c.margins(bc)[k] for k in use)
            print(f"| {label} | {c.size_bytes:,} | {psnr_cells([c.psnr_per_mip[k] for k in use], c.psnr)} | {worst:+.1f} |")


if __name__ == "__main__":
    main()
