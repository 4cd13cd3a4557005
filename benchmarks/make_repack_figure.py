"""docs/layout_repack.png: BC@R against its BC7 repack in the same bytes, close up, on the two sets
where the repack gains most: usdwg_texture_file_formats' RGBA colour chart (albedo BC1 + opacity BC4
in BC@R; mip 0) and the sample scene's Tiles (its ORM file in BC1; mip 1, where BC@R loses most),
each panel's PSNR over the crop: the 64² window where BC@R's error exceeds the repack's most. The
blocks are the ones a build ships (`bcfpipe.layout.classic.encode` and `measure_repack`, which
tests/test_repack_layout.py checks against the exported files).

  python benchmarks/make_repack_figure.py [--png docs/layout_repack.png]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, SHARED  # noqa: E402

CHART = SHARED / "usdwg_texture_file_formats" / "png_rgb_8-bit.usda"


def job_set(scene: Path, material: str):
    """(texture set, R, addressing) of the job that builds ``material`` with no option."""
    from bcfpipe.builder.plan import plan
    from bcfpipe.texset.texture_set import TextureSpec, load_texture_set

    job = next(j for j in plan(scene).jobs if any(m.endswith(material) for m in j.materials))
    ts = load_texture_set([TextureSpec(sem, path, ch) for sem, path, ch in job.specs])
    return ts, max(ts.width, ts.height), job.wrap


def panels(ts, r, wrap, channels, mip):
    """Mip ``mip`` of ``channels``: the reference, BC@R and the best repack (by all-mip PSNR)."""
    from bcfpipe.layout import choose as C
    from bcfpipe.layout.classic import channel_errors, encode, measure_repack, repacks
    from bcfpipe.texset.texture_set import build_mip_chain

    ref = build_mip_chain(ts.data)
    groups = encode(ts, r, ref, wrap)
    e_bc = channel_errors(ts, groups, ref)
    bc0 = np.zeros_like(ref[mip])
    for g in groups:
        bc0[..., list(g.group.channels)] = g.decoded[mip]
    best, best_psnr = None, -1.0
    for rp in repacks([g.group for g in groups]):
        enc, e, _ = measure_repack(ts, groups, e_bc, rp, r, ref, wrap=wrap)
        psnr = C.Candidate((), None, 0, C.combine(None, e, range(ts.num_channels)), "measured").psnr
        if psnr > best_psnr:
            out = bc0.copy()
            for g in enc:
                out[..., list(g.group.channels)] = g.decoded[mip]
            best, best_psnr, label = out, psnr, rp.label
    return [ref[mip][..., channels], bc0[..., channels], best[..., channels]], label


def worst_window(imgs, size: int = 64) -> tuple[slice, slice]:
    """The ``size``² window (on a half-window grid) where BC@R's squared error exceeds the repack's most."""
    ref, bc, rp = imgs
    gain = ((bc - ref) ** 2 - (rp - ref) ** 2).sum(-1)
    h, w = gain.shape
    best = max(((gain[y:y + size, x:x + size].sum(), y, x) for y in range(0, h - size + 1, size // 2)
                for x in range(0, w - size + 1, size // 2)))
    return slice(best[1], best[1] + size), slice(best[2], best[2] + size)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--png", type=Path, default=Path("docs/layout_repack.png"))
    a = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bcfpipe.texset.metrics import psnr_from_mse

    rows = []
    ts, r, wrap = job_set(CHART, "MainMaterialWithOpacity")
    albedo = [i for i, c in enumerate(ts.channels) if c.semantic == "albedo"]
    rows.append(("colour chart, albedo, mip 0", panels(ts, r, wrap, albedo, 0)))
    ts, r, wrap = job_set(REPO / "samples" / "sample_scene.usda", "Tiles")
    rough = [i for i, c in enumerate(ts.channels) if c.semantic == "roughness"]
    rows.append(("sample Tiles, roughness (ORM file), mip 1", panels(ts, r, wrap, rough, 1)))

    fig, axes = plt.subplots(len(rows), 3, figsize=(10.5, 3.7 * len(rows)))
    for row, (name, (imgs, label)) in zip(axes, rows):
        crop = worst_window(imgs)
        ref = imgs[0][crop]
        for ax, img, title in zip(row, imgs, ("reference", "BC@R (BC1 + BC4)" if "chart" in name else "BC@R (BC1)",
                                               f"BC@R with {label}")):
            part = np.clip(img[crop], 0, 1)
            ax.imshow(part[..., 0] if part.shape[-1] == 1 else part, cmap="gray", vmin=0, vmax=1,
                      interpolation="nearest")
            ax.set_xticks([]), ax.set_yticks([])
            db = "" if img is imgs[0] else f", {psnr_from_mse(float(np.mean((part - ref) ** 2))):.1f} dB"
            ax.set_title(f"{title}{db}", fontsize=9)
        row[0].set_ylabel(name, fontsize=9)
    fig.suptitle("Close up: BC@R against its BC7 repack in the same bytes (PSNR over the crop)", fontsize=10)
    fig.tight_layout()
    fig.savefig(a.png, dpi=110)
    print(f"wrote {a.png}")


if __name__ == "__main__":
    main()
