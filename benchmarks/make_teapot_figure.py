"""docs/teapot_albedo.png: `bcfpipe decode` of the teapot albedo at lod 0, next to the reference
and BC1@1024 (quicktex level 18, magnified bilinearly to 2048 as a renderer would at lod 0).

  python benchmarks/make_teapot_figure.py BUILD_OUT [--crop Y X SIZE] [--png docs/teapot_albedo.png]
BUILD_OUT is a `bcfpipe build` of Teapot.usd (Fancy variant); the decode runs the GLSL runtime.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import TEAPOT  # noqa: E402

from bcfpipe.texset.baselines import encode_texture_set_baseline  # noqa: E402
from bcfpipe.texset.metrics import psnr_from_mse  # noqa: E402
from bcfpipe.texset.texture_set import TextureSpec, build_mip_chain, load_texture_set  # noqa: E402


def read(path: Path) -> np.ndarray:
    import OpenImageIO as oiio

    return np.asarray(oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT))[..., :3]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("build", type=Path)
    ap.add_argument("--material", default="/Teapot/Materials/PorcelainFlowers")
    ap.add_argument("--crop", type=int, nargs=3, default=(700, 860, 256), metavar=("Y", "X", "SIZE"))
    ap.add_argument("--png", type=Path, default=Path("docs/teapot_albedo.png"))
    ap.add_argument("--backend", default="glsl")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bcf = Path(sys.executable).with_name("bcfpipe")
        subprocess.run([str(bcf), "decode", str(a.build), "--material", a.material, "--lod", "0",
                        "--backend", a.backend, "-o", tmp], check=True)
        albedo = next(p for p in Path(tmp).iterdir() if "albedo" in p.name or "diffuse" in p.name.lower())
        neural = read(albedo)
    ts = load_texture_set([TextureSpec.parse(f"albedo={TEAPOT / 'tea_set_01_diff_2k.jpg'}:rgb")])
    ref = ts.data
    bc1 = encode_texture_set_baseline(ts, "bc", 1024, ref_mips=build_mip_chain(ref))[0][0]
    y, x, n = a.crop
    crops = [("reference (2048², JPEG)", ref), ("BCf 1k fast (bcfpipe decode, GLSL)", neural), ("BC1@1024, magnified", bc1)]
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.4), dpi=110)
    for ax, (name, img) in zip(axes, crops):
        mse = float(np.mean((img[y:y + n, x:x + n] - ref[y:y + n, x:x + n]) ** 2))
        ax.imshow(np.clip(img[y:y + n, x:x + n], 0, 1), interpolation="nearest")
        ax.set_title(name + ("" if img is ref else f"\ncrop PSNR {psnr_from_mse(mse):.2f} dB"), fontsize=9)
        ax.axis("off")
    fig.suptitle(f"teapot albedo at lod 0, crop {n}x{n} at ({x}, {y})", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.92))
    a.png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(a.png)
    print(f"wrote {a.png}")


if __name__ == "__main__":
    main()
