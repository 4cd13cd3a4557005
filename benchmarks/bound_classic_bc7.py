"""Issue 31: classic groups repacked as BC7 at equal bytes, against BC@R, per mip. An oracle: no
training, every figure from encoded and decoded blocks.

BC@R ships a colour (or packed) group as BC1 (4 bits per texel) and a lone scalar as BC4 (4 bits
per texel). One BC7 RGBA texture (8 bits per texel) holds both in the same bytes, with 4-bit
indices, 7-bit endpoints and partitions, and the alpha channel either shared with the colour
(modes 6, 7) or separate (modes 4, 5). Each candidate below merges one BC1 group with one BC4
group into BC7 (ISPC, `bcfpipe.texset.baselines.BC7_SETTINGS`; texture2ddecoder decodes), the
other groups as BC@R has them; "all BC7" packs every channel, four per texture, where that fits
BC@R's bytes.

Sets: ``teapot`` and ``brick`` at R = 1024 over every texel, and ``sample:NAME``: a texture set of
samples/sample_scene.usda as a build with no option settles it (R = its source side, over the
texels the meshes read).

  python benchmarks/bound_classic_bc7.py [--sets teapot,brick,sample:Bricks,sample:Tiles,sample:Leaves]
"""
from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import specs  # noqa: E402
from common import machine  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent


def load(name: str):
    """(texture set, R, level-0 coverage mask or None, addressing)."""
    from bcfpipe.texset.texture_set import TextureSpec, load_texture_set

    if not name.startswith("sample:"):
        return load_texture_set(specs(name)), 1024, None, "repeat"
    from bcfpipe.builder.plan import plan
    from bcfpipe.scan.coverage import unpack

    bp = plan(ROOT / "samples" / "sample_scene.usda")
    job = bp.job(name.split(":", 1)[1])
    ts = load_texture_set([TextureSpec(sem, path, ch) for sem, path, ch in job.specs])
    mask = unpack(job.coverage, ts.width, ts.height) if job.coverage is not None else None
    return ts, max(ts.width, ts.height), mask, job.wrap


def bc7_errors(ts, channels, ref, resolution, masks, wrap):
    """(mips, len(channels)) MSE of ``channels`` stored in BC7 textures, four per texture."""
    from bcfpipe.formats.dds import HEADER_BYTES
    from bcfpipe.layout.classic import magnify
    from bcfpipe.texset.baselines import _from_storage, _to_storage, bc7_mips
    from bcfpipe.texset.metrics import mse_per_mip

    d = sum(1 for m in ref if max(m.shape[:2]) > resolution)
    normal = np.array([ch.kind == "normal" for ch in ts.channels])
    err = np.zeros((len(ref), len(channels)))
    size = 0
    for t in range(0, len(channels), 4):
        idx = list(channels[t:t + 4])
        stored = [_to_storage(m[..., idx], normal[idx]) for m in ref[d:]]
        padded = [np.concatenate([s, np.zeros(s.shape[:2] + (4 - len(idx),), np.float32)], -1) if len(idx) < 4
                  else s for s in stored]
        out, nbytes = bc7_mips(padded)
        size += nbytes + HEADER_BYTES
        dec = [_from_storage(o[..., :len(idx)], normal[idx]) for o in out]
        dec = [magnify(dec[0], *ref[k].shape[:2], wrap) for k in range(d)] + dec
        for j, c in enumerate(idx):
            err[:, t + j] = mse_per_mip([r[..., c:c + 1] for r in ref], [m[..., j:j + 1] for m in dec],
                                        [ts.channels[c]], None, masks)
    return err, size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="teapot,brick,sample:Bricks,sample:Tiles,sample:Leaves")
    args = ap.parse_args()

    from bcfpipe.layout import choose as C
    from bcfpipe.layout.classic import channel_errors, encode
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
        merges = [(a, b) for a, b in itertools.permutations(groups, 2)
                  if a.group.format == "bc1" and b.group.format == "bc4"]
        layouts = [([a, b], f"{a.group.name} + {b.group.name} as BC7") for a, b in merges]
        n4 = -(-ts.num_channels // 4)
        if n4 * r * r * 4 // 3 <= bc.size_bytes:  # BC7: a byte per texel, every mip
            layouts.append((list(groups), f"all {ts.num_channels} channels in {n4} BC7"))
        for merged, label in layouts:
            cols = [c for g in merged for c in g.group.channels]
            e7, size7 = bc7_errors(ts, cols, ref, r, masks, wrap)
            e = e_bc.copy()
            e[:, cols] = e7
            size = bc.size_bytes - sum(g.size_bytes for g in merged) + size7
            rows.append((label, C.Candidate((), None, size, tuple(float(v) for v in e.mean(1)), "measured", use)))
        print(f"\n### {name} (R = {r}, {ts.num_channels} channels{', over the texels read' if mask is not None else ''};"
              f" {time.perf_counter() - t0:.0f} s)\n")
        mips = " | ".join(f"mip {k}" for k in use)
        print(f"| layout | bytes | {mips} | all mips | worst margin |")
        print("|---|---:|" + "---:|" * len(use) + "---:|---:|")
        for label, c in rows:
            worst = min(c.margins(bc)[k] for k in use)
            print(f"| {label} | {c.size_bytes:,} | " + " | ".join(f"{c.psnr_per_mip[k]:.1f}" for k in use)
                  + f" | **{c.psnr:.2f}** | {worst:+.1f} |")


if __name__ == "__main__":
    main()
