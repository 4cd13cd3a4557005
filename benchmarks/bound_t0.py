"""Issues #9 and #29: how much fine-mip fidelity can 1024² feature textures carry at all, per format?

An oracle that no training can beat by much: the reference's own principal components at mip 1
(1024² for a 2048² set), written as block-compressed textures and decoded, then mapped back to the
channels by the exact linear inverse. It is measured at mip 1 (the features' own resolution) and at
mip 0 (magnified bilinearly, as BC@1024 is there), against BC@1024 in the same run.

Every compressed row but the last spends **one byte per texel at 1024²**, the bytes of BCf's T_0:

* ``BC6H 11110``: 3 PCs in one BC6H mode-11110 texture (bcfpipe's encoder, spec decoder);
* ``BC7 mode 6``: 4 PCs in one BC7 texture of mode 6 only (one subset, RGBA, 7-bit endpoints plus a
  p-bit, 4-bit indices);
* ``BC7 modes 1/3/7``: the partitioned modes only (two subsets; mode 7 carries alpha);
* ``BC7 modes 1/3/7+6``: those and mode 6, the encoder's choice per block (ISPC picks mode 7 or 6
  for every block of a four-channel image, so this is modes 6 and 7);
* ``bcfpipe modes 6+7``: bcfpipe's own encoder (bcfpipe.bc7.encode7), the blocks
  ``--features bc7`` could write;
* ``BC7 free``: every mode, the encoder's choice;
* ``2×BC1``: 6 PCs in two BC1 textures (4 bits per texel each).

BC7 and BC1 rows use Intel's ISPC encoder (``ispc-texcomp``, profile ``alpha_slow``'s refinement,
restricted to the modes named) and ``texture2ddecoder`` as decoder; both take 8-bit input, so
the components are quantized to 8 bits first, as any UNORM feature would be. ``float`` rows are the
same components unquantized: what the format loses is the gap between the two. The last row spends
one more BC6H texture on every component.

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

F_LO, F_HI = 0.25, 1.7  # BC6H feature range the components are mapped to (decoded values)
BC7_REFINE = 4          # ISPC alpha_slow: 2 + moreRefine iterations for every mode


def _bc6h(img: np.ndarray) -> np.ndarray:
    from bcfpipe.bc6h import decode, encode

    h, w = img.shape[:2]
    lifted = F_LO + img * (F_HI - F_LO)
    return (decode(encode(lifted.astype(np.float32)), w, h).reshape(h, w, 3) - F_LO) / (F_HI - F_LO)


def _rgba8(img: np.ndarray) -> tuple[bytes, np.ndarray]:
    h, w, c = img.shape
    px = np.zeros((h, w, 4), np.uint8)
    px[..., 3] = 255
    px[..., :c] = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
    return px.tobytes(), px


def _bgra_to_unit(raw: bytes, h: int, w: int, c: int) -> np.ndarray:
    px = np.frombuffer(raw, np.uint8).reshape(h, w, 4)[..., [2, 1, 0, 3]]
    return px[..., :c].astype(np.float64) / 255.0


def _bc7(img: np.ndarray, modes: str) -> np.ndarray:
    """BC7-encode an (H, W, 4) image in [0, 1] with ISPC, restricted to ``modes`` (ISPC's four
    groups: '02', '137', '45', '6'), and decode it."""
    import ispc_texcomp as ispc
    import texture2ddecoder

    groups = ("02", "137", "45", "6")
    sel = [g in modes.split(",") for g in groups]
    settings = ispc.BC7EncSettings(sel, [BC7_REFINE] * 8, False, 64, 64, 64, 0, BC7_REFINE, 4)
    h, w = img.shape[:2]
    raw, _ = _rgba8(img)
    blocks = ispc.compress_blocks_bc7(ispc.RGBASurface(raw, w, h), settings)
    return _bgra_to_unit(texture2ddecoder.decode_bc7(blocks, w, h), h, w, 4)


def _bcfpipe_bc7(img: np.ndarray) -> np.ndarray:
    """BC7 modes 6 and 7 through bcfpipe's encoder and decoder, from the same 8-bit input."""
    from bcfpipe.bc7 import encode7, modes

    h, w = img.shape[:2]
    u8 = np.rint(np.clip(img, 0.0, 1.0) * 255.0) / 255.0
    texels = u8.reshape(h // 4, 4, w // 4, 4, 4).transpose(0, 2, 1, 3, 4).reshape(-1, 16, 4)
    dec = modes.interpolate(*encode7.encode_params(texels)).astype(np.float64) / 255.0
    return dec.reshape(h // 4, w // 4, 4, 4, 4).transpose(0, 2, 1, 3, 4).reshape(h, w, 4)


def _bc1(img: np.ndarray) -> np.ndarray:
    import ispc_texcomp as ispc
    import texture2ddecoder

    h, w = img.shape[:2]
    raw, _ = _rgba8(img)
    blocks = ispc.compress_blocks_bc1(ispc.RGBASurface(raw, w, h))
    return _bgra_to_unit(texture2ddecoder.decode_bc1(blocks, w, h), h, w, 3)


def _float8(img: np.ndarray) -> np.ndarray:
    return np.rint(img * 255.0) / 255.0


# codec: (channels per texture, round trip of an (H, W, channels) image in [0, 1])
CODECS = {
    "float": (None, lambda img: img),
    "8-bit": (None, _float8),
    "BC6H 11110": (3, _bc6h),
    "BC7 mode 6": (4, lambda img: _bc7(img, "6")),
    "BC7 modes 1/3/7": (4, lambda img: _bc7(img, "137")),
    "BC7 modes 1/3/7+6": (4, lambda img: _bc7(img, "137,6")),
    "bcfpipe modes 6+7": (4, lambda img: _bcfpipe_bc7(img)),
    "BC7 free": (4, lambda img: _bc7(img, "02,137,45,6")),
    "BC1": (3, _bc1),
}


def oracle(ref1: np.ndarray, n_pc: int, codec: str) -> np.ndarray:
    """Reconstruction of ``ref1`` (H, W, c) from its first ``n_pc`` principal components, each
    mapped to [0, 1] by its range and stored through ``codec``, texture by texture."""
    h, w, c = ref1.shape
    x = ref1.reshape(-1, c).astype(np.float64)
    mean = x.mean(0)
    _, _, vt = np.linalg.svd(x - mean, full_matrices=False)
    axes = vt[:n_pc]
    pcs = (x - mean) @ axes.T
    lo, hi = pcs.min(0), pcs.max(0)
    span = np.where(hi > lo, hi - lo, 1.0)
    feat = (pcs - lo) / span
    per_tex, roundtrip = CODECS[codec]
    per_tex = per_tex or n_pc
    for j in range(0, n_pc, per_tex):
        cols = list(range(j, min(j + per_tex, n_pc)))
        img = np.zeros((h, w, per_tex))
        img[..., :len(cols)] = feat[:, cols].reshape(h, w, -1)
        feat[:, cols] = roundtrip(img).reshape(-1, per_tex)[:, :len(cols)]
    back = (feat * span + lo) @ axes + mean
    return back.reshape(h, w, c).astype(np.float32)


def rows_for(c: int) -> list[tuple[str, int, str, str]]:
    """(label, PCs, codec, bytes) for a set of ``c`` channels."""
    k3, k4, k6 = min(3, c), min(4, c), min(6, c)
    n_tex = -(-c // 3)
    return [
        (f"{k3} PCs", k3, "float", "float"),
        (f"{k3} PCs", k3, "BC6H 11110", "1 B/texel"),
        (f"{k4} PCs", k4, "float", "float"),
        (f"{k4} PCs", k4, "8-bit", "4 B/texel"),
        (f"{k4} PCs", k4, "BC7 mode 6", "1 B/texel"),
        (f"{k4} PCs", k4, "BC7 modes 1/3/7", "1 B/texel"),
        (f"{k4} PCs", k4, "BC7 modes 1/3/7+6", "1 B/texel"),
        (f"{k4} PCs", k4, "bcfpipe modes 6+7", "1 B/texel"),
        (f"{k4} PCs", k4, "BC7 free", "1 B/texel"),
        (f"{k6} PCs", k6, "float", "float"),
        (f"{k6} PCs", k6, "BC1", "1 B/texel (2×BC1)" if k6 > 3 else "0.5 B/texel"),
        (f"all {c} PCs", c, "BC6H 11110", f"{n_tex} B/texel ({n_tex}×BC6H)"),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="teapot,brick")
    args = ap.parse_args()

    from bcfpipe.texset.baselines import _bilinear_up, encode_texture_set_baseline
    from bcfpipe.texset.metrics import mse_per_mip, psnr_from_mse
    from bcfpipe.texset.texture_set import build_mip_chain, load_texture_set

    print(f"machine: {machine()}")
    print("| set | components | stored as | bytes at 1024² | mip 0 | mip 1 |")
    print("|---|---|---|---|---:|---:|")
    for name in args.sets.split(","):
        ts = load_texture_set(specs(name))
        ref = build_mip_chain(ts.data)
        c = ts.data.shape[2]

        def report(label: str, stored: str, size: str, d0: np.ndarray, d1: np.ndarray) -> None:
            m0, m1 = mse_per_mip(ref[:2], [d0, d1], ts.channels)
            print(f"| {name} ({c} ch) | {label} | {stored} | {size} | {psnr_from_mse(m0):.1f} "
                  f"| {psnr_from_mse(m1):.1f} |", flush=True)

        bc, size = encode_texture_set_baseline(ts, "bc", 1024, ref_mips=ref)
        report("BC@1024", "BC1/BC4/BC5", f"{size / 2**20:.2f} MiB with mips", bc[0], bc[1])
        for label, n_pc, codec, size in rows_for(c):
            rec = oracle(ref[1], n_pc, codec)
            report(label, codec, size, _bilinear_up(rec, *ref[0].shape[:2]), rec)


if __name__ == "__main__":
    main()
