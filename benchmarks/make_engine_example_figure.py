"""docs/engine_example.png: examples/vulkan_decode.py (the shipped SPIR-V, driven as an engine would,
no bcfpipe code) beside `bcfpipe decode --backend onnx` for one material at a few lods, and the
8-bit differences between their PNGs (docs/format.md, "An engine's eye").

  python benchmarks/make_engine_example_figure.py BUILD_OUT --material Bricks [--lods 0 2.5] [--size 512]
BUILD_OUT is a neural build, e.g. `bcfpipe build samples/sample_scene.usda --layout neural --quality draft`.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, machine  # noqa: E402


def read_png(path: Path) -> np.ndarray:
    import OpenImageIO as oiio

    return np.asarray(oiio.ImageBuf(str(path)).get_pixels(oiio.UINT8))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--material", required=True)
    ap.add_argument("--lods", type=float, nargs="+", default=[0.0, 2.5])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--png", type=Path, default=REPO / "docs" / "engine_example.png")
    args = ap.parse_args()
    folder = args.out / "materials" / args.material
    semantics = list(dict.fromkeys(o["semantic"] for o in json.loads((folder / "material.json").read_text())["outputs"]
                                   if o.get("source") != "classic"))
    rows, figures = [], []
    with tempfile.TemporaryDirectory() as d:
        for lod in args.lods:
            ex, ours = Path(d) / f"example_{lod}", Path(d) / f"decode_{lod}"
            subprocess.run([sys.executable, str(REPO / "examples" / "vulkan_decode.py"), str(folder), "-o", str(ex),
                            "--lod", str(lod), "--size", str(args.size)], check=True, capture_output=True)
            subprocess.run([sys.executable, "-m", "bcfpipe", "decode", str(args.out), "--material", args.material,
                            "--backend", "onnx", "-o", str(ours), "--lod", str(lod),
                            "--size", f"{args.size}x{args.size}"], check=True, capture_output=True)
            row = []
            for sem in semantics:
                if not (ours / f"{sem}.png").is_file():
                    continue  # an HDR output: bcfpipe decode writes EXR
                a, b = read_png(ex / f"{sem}.png").astype(int), read_png(ours / f"{sem}.png").astype(int)
                diff = np.abs(a - b)
                figures.append({"lod": lod, "output": sem, "max_8bit": int(diff.max()),
                                "differing": float((diff > 0).mean())})
                row.append((sem, a, b))
            rows.append((lod, row))
    print(f"# {args.material}, {args.size}², examples/vulkan_decode.py against bcfpipe decode --backend onnx; {machine()}")
    print("| lod | output | max 8-bit difference | values that differ |")
    print("|---|---|---|---|")
    for f in figures:
        print(f"| {f['lod']:g} | {f['output']} | {f['max_8bit']} | {100 * f['differing']:.2f}% |")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [r for r in rows[0][1] if r[0] in ("albedo", "normal")] or rows[0][1][:2]
    names = [s for s, _, _ in shown]
    fig, axes = plt.subplots(len(rows), 2 * len(names), figsize=(3 * 2 * len(names), 3.2 * len(rows)), squeeze=False)
    for r, (lod, row) in enumerate(rows):
        for k, (sem, a, b) in enumerate(x for x in row if x[0] in names):
            for j, (img, who) in enumerate(((a, "vulkan_decode.py"), (b, "bcfpipe decode"))):
                ax = axes[r][2 * k + j]
                ax.imshow(img.squeeze(), cmap="gray" if img.shape[-1] == 1 else None, vmin=0, vmax=255)
                ax.set_title(f"{sem}, s = {lod:g}: {who}", fontsize=9)
                ax.axis("off")
    fig.tight_layout()
    fig.savefig(args.png, dpi=72)
    print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
