"""Issue #9: how much fine-mip fidelity can BC6H feature textures at 1024² carry at all?

An oracle that no training can beat by much: the reference's own principal components at mip 1
(1024² for a 2048² set), written as BC6H mode-11110 textures by bcfpipe's encoder and decoded by the
spec decoder, then mapped back to the channels by the exact linear inverse. It is measured at
mip 1 (the features' own resolution) and at mip 0 (magnified bilinearly, as BC@1024 is there),
against BC@1024 in the same run. ``3 PCs`` is what one feature texture (BCf's T_0) holds;
``all PCs`` spends one more 1024² BC6H texture (2.67 MiB with mips) to hold every channel.

  python benchmarks/bound_t0.py [--sets teapot,brick]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_fidelity import specs  # noqa: E402
from common import machine  # noqa: E402

F_LO, F_HI = 0.25, 1.7  # feature range the components are mapped to (decoded BC6H values)


def oracle(ref1: np.ndarray, n_pc: int, encode: bool) -> np.ndarray:
    """Reconstruction of ``ref1`` (H, W, c) from its first ``n_pc`` principal components, stored as
    floats or as BC6H textures of three components each."""
    from bcfpipe.bc6h import decode
    from bcfpipe.bc6h import encode as bc6h_encode

    h, w, c = ref1.shape
    x = ref1.reshape(-1, c).astype(np.float64)
    mean = x.mean(0)
    _, _, vt = np.linalg.svd(x - mean, full_matrices=False)
    axes = vt[:n_pc]
    pcs = (x - mean) @ axes.T
    lo, hi = pcs.min(0), pcs.max(0)
    span = np.where(hi > lo, hi - lo, 1.0)
    feat = F_LO + (pcs - lo) / span * (F_HI - F_LO)
    if encode:
        for j in range(0, n_pc, 3):
            cols = list(range(j, min(j + 3, n_pc)))
            img = np.full((h, w, 3), F_LO, np.float32)
            img[..., :len(cols)] = feat[:, cols].reshape(h, w, -1)
            dec = decode(bc6h_encode(img), w, h).reshape(-1, 3).astype(np.float64)
            feat[:, cols] = dec[:, :len(cols)]
    back = ((feat - F_LO) / (F_HI - F_LO) * span + lo) @ axes + mean
    return back.reshape(h, w, c).astype(np.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="teapot,brick")
    args = ap.parse_args()

    from bcfpipe.bench.baselines import _bilinear_up, encode_texture_set_baseline
    from bcfpipe.texset.metrics import mse_per_mip, psnr_from_mse
    from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set

    print(f"machine: {machine()}")
    print("| set | method | bits at 1024² | mip 0 | mip 1 |")
    print("|---|---|---|---:|---:|")
    for name in args.sets.split(","):
        ts = load_texture_set(specs(name))
        ref = build_mip_chain(ts.data)
        bc, size = encode_texture_set_baseline(ts, "bc", 1024, ref_mips=ref)
        rows = [("BC@1024", f"{size / 2**20:.2f} MiB", bc[0], bc[1])]
        c = ts.data.shape[2]
        for n_pc, label in ((3, "3 PCs"), (c, "all PCs")):
            n_tex = -(-n_pc // 3)
            for enc in (False, True):
                rec = oracle(ref[1], n_pc, enc)
                up = _bilinear_up(rec, *ref[0].shape[:2])
                bits = f"{n_tex} BC6H ({n_tex * 4 / 3:.2f} MiB)" if enc else "float"
                rows.append((f"{label} ({n_pc}), {'BC6H' if enc else 'float'}", bits, up, rec))
        for method, bits, d0, d1 in rows:
            m0, m1 = mse_per_mip(ref[:2], [d0, d1], ts.channels)
            print(f"| {name} ({c} ch) | {method} | {bits} | {psnr_from_mse(m0):.1f} | {psnr_from_mse(m1):.1f} |",
                  flush=True)


if __name__ == "__main__":
    main()
