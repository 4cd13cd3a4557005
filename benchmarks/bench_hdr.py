"""HDR precision (issue 33): an emissive ramp from 0 to 3,000, trained with `bcfpipe train`, then
measured from the exported files (BC6H DDS + fp16 weights through onnxruntime, in source units
via material.json's value_scale/value_bias).

    .venv/bin/python benchmarks/bench_hdr.py [--size 256] [--profile tiny] [--quality draft] [--wrap clamp] [--kernel auto]
        [--layout neural]

Prints, per mip: mean |log1p(decoded) - log1p(source)| over every texel and channel, the median
relative error of texels whose source value lies in [1, 10], and the PSNR against the peak.
The ramp: R rises linearly along x (0..3000), G exponentially along y (expm1(y ln 3001)), B
exponentially along the diagonal, so every decade from 0.1 to 3,000 holds many texels. A ramp
does not tile: --wrap clamp is its addressing (with repeat, the 3,000 -> 0 seam costs the texels
beside it). --layout neural (the default here) measures the log-domain decoder of issue 33;
--layout auto, what `train` ships by default (issue 50: BC@R's BC6H_UF16 for this ramp).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, run_bcfpipe  # noqa: E402

PEAK = 3000.0


def hdr_ramp(n: int, peak: float = PEAK) -> np.ndarray:
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n
    log_peak = np.log1p(peak)
    return np.stack([x * peak, np.expm1(y * log_peak), np.expm1((x + y) / 2 * log_peak)], -1).astype(np.float32)


def write_exr(path: Path, a: np.ndarray) -> Path:
    import OpenImageIO as oiio

    h, w, c = a.shape
    buf = oiio.ImageBuf(oiio.ImageSpec(w, h, c, "half"))
    buf.set_pixels(oiio.ROI(), np.ascontiguousarray(a, np.float32))
    assert buf.write(str(path)), buf.geterror()
    return path


def measure(out: Path, source: np.ndarray) -> list[dict]:
    """Per mip: mean |log1p error|, median relative error in [1, 10], PSNR against the peak."""
    from bcfpipe.export import writer as E
    from bcfpipe.texset.texture_set import build_mip_chain

    desc = json.loads((out / "material.json").read_text())
    scale = np.array([o["value_scale"] for o in desc["outputs"]], np.float32)
    bias = np.array([o["value_bias"] for o in desc["outputs"]], np.float32)
    ref = build_mip_chain(np.asarray(source, np.float32))
    dec = E.decode_mips(E.load(out), [m.shape[:2] for m in ref])
    rows = []
    for k, (r, d) in enumerate(zip(ref, dec)):
        v = d * scale + bias
        log_err = float(np.abs(np.log1p(np.maximum(v, 0)) - np.log1p(r)).mean())
        band = (r >= 1) & (r <= 10)
        rel = float(np.median(np.abs(v[band] - r[band]) / r[band])) if band.any() else float("nan")
        mse = float(((v.astype(np.float64) - r) ** 2).mean())
        psnr = 10 * np.log10(PEAK ** 2 / mse) if mse > 0 else float("inf")
        rows.append({"mip": k, "log1p_error": log_err, "median_rel_error_1_10": rel, "texels_1_10": int(band.sum()),
                     "psnr_peak": psnr})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_options(ap, size=256, profile="tiny", quality="draft")
    ap.add_argument("--wrap", default="clamp", choices=("clamp", "repeat"))
    ap.add_argument("--kernel", default="auto", help="bcfpipe train --kernel (issue 30)")
    ap.add_argument("--layout", default="neural", choices=("neural", "auto"),
                    help="bcfpipe train --layout: neural (the decoder, issue 33) or auto (train's default)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        ramp = hdr_ramp(a.size)
        src = write_exr(tmp / "hdr.exr", ramp)
        _, p = run_bcfpipe("train", f"emissiveColor={src}:rgb", "-o", tmp / "out", "--profile", a.profile,
                           "--quality", a.quality, "--wrap", a.wrap, "--kernel", a.kernel, "--layout", a.layout, "--json")
        if p.returncode:
            raise SystemExit(p.stderr)
        import OpenImageIO as oiio

        stored = np.asarray(oiio.ImageBuf(str(src)).get_pixels(oiio.FLOAT)).reshape(ramp.shape)  # half-rounded
        rows = measure(tmp / "out", stored)
        enc = [o.get("log_gain") for o in json.loads((tmp / "out" / "material.json").read_text())["outputs"]]
    if a.json:
        print(json.dumps({"size": a.size, "profile": a.profile, "quality": a.quality, "wrap": a.wrap, "layout": a.layout,
                          "log_gain": enc,
                          "mips": rows}))
        return
    print(f"HDR ramp 0..{PEAK:g}, {a.size}^2, --profile {a.profile} --quality {a.quality} --wrap {a.wrap} "
          f"--layout {a.layout}; "
          f"log gain per output: {enc}")
    print(f"{'mip':>3} {'mean |log1p err|':>17} {'median rel err [1,10]':>22} {'texels':>7} {'PSNR/peak':>10}")
    for r in rows:
        print(f"{r['mip']:>3} {r['log1p_error']:>17.4f} {r['median_rel_error_1_10']:>22.2%} {r['texels_1_10']:>7} "
              f"{r['psnr_peak']:>10.2f}")


if __name__ == "__main__":
    main()
