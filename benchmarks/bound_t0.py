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
* ``bcfpipe modes 6+7``: bcfpipe's own encoder (benchmarks/bc7_mode7/encode7.py), the blocks
  ``--features bc7`` could write;
* ``BC7 free``: every mode, the encoder's choice;
* ``2×BC1``: 6 PCs in two BC1 textures (4 bits per texel each).

BC7 and BC1 rows use Intel's ISPC encoder (``ispc-texcomp``, profile ``alpha_slow``'s refinement,
restricted to the modes named) and ``texture2ddecoder`` as decoder; both take 8-bit input, so
the components are quantized to 8 bits first, as any UNORM feature would be. ``float`` rows are the
same components unquantized: what the format loses is the gap between the two. The last row spends
one more BC6H texture on every component.

  python benchmarks/bound_t0.py [--sets teapot,brick]

Issue 52, ``--widths``: what a wider T_0 can hold. T_0's components as the shipped ``--t0 pca``
computes them (`bcfpipe.train.feature_init.pca_init`: axes from a 256² mip, each T_0 mip holding
the reference at the lod it is read at, 0.1-99.9 % range onto [0.02, 0.98]), widened to k = 4, 8
and 12 components in ⌈k/4⌉ BC7 textures (ISPC, `bcfpipe.texset.baselines.BC7_SETTINGS`, every
mode, as the shipped T_0 is encoded), or 4 in BC7 plus components 5-7 in one BC1 texture (the
8th held at its mean), at T_0 = R and 2R (R = half the set's side: 1024² for a 2048² set).
Reconstructed by pca_init's linear decoder (the exact inverse; no training) with the decoder's
output clamp. Mip 0 reads T_0 at R magnified bilinearly, as BC@R's is. Against, at the same mips:
BC@R (BC1/BC4/BC5, `encode_texture_set_baseline`) and the BC7 quality set at R (`bc7_quality_set`:
BC@R's packing with BC7 for every colour or packed-file texture). Bytes are GPU bytes with every
mip; a T_0 row counts T_0 only (a 1k model adds 0.44 MiB of T_1..T_3).

``--resolution R`` sets R (a power of two up to the set's side; by default half the side). A T_0
of more texels than the source (2R past the side) is skipped, and the output says so.

  python benchmarks/bound_t0.py --widths [--sets teapot,brick,wood,bottle] [--crop 256] [--workers 1]
      [--resolution 2048]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, specs  # noqa: E402

F_LO, F_HI = 0.25, 1.7  # BC6H feature range the components are mapped to (decoded values)
BC7_REFINE = 4          # ISPC alpha_slow: 2 + moreRefine iterations for every mode


def _bc6h(img: np.ndarray) -> np.ndarray:
    from bcfpipe.bc6h import decode
    from bcfpipe.bc6h.encode import encode

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
    from bc7_mode7 import encode7, modes

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


def bc7_quality_set(ts, res: int, ref: list[np.ndarray]) -> tuple[list[np.ndarray], int]:
    """The BC7 quality set at ``res``: BC@R's textures (`pack_texture_set` 'bc') with every BC1
    texture, a colour or a packed file, in BC7 (ISPC, every mode; alpha 1); BC5 normals, BC4 lone
    scalars and BC6H HDR colour as BC@R has them. Returns (decoded reference mips 0 and 1, GPU bytes
    of every mip)."""
    from bcfpipe.texset.baselines import (bilinear_up, from_storage, _to_storage, bc4_mips, bc5_mips,
                                          bc6h_mips, bc7_mips, hdr_value_map, pack_texture_set)

    d = int(round(math.log2(max(ts.width, ts.height) / res)))
    src = ref[d:]
    normal = np.array([ch.kind == "normal" for ch in ts.channels])
    low = [np.zeros_like(m) for m in src]
    total = 0
    for fmt, idx in pack_texture_set(ts, "bc"):
        stored = [_to_storage(m[..., idx], normal[idx]) for m in src]
        if fmt == "bc6h":
            scale, bias = hdr_value_map(ts, idx)
            out, size = bc6h_mips([m[..., idx] * scale + bias for m in src])
            out = [(o - bias) / scale for o in out]
        elif fmt == "bc5":
            out, size = bc5_mips(stored)
        elif fmt == "bc4":
            out, size = bc4_mips(stored)
        else:  # bc1 -> bc7: RGB (a single channel replicated, two with b = 0), alpha 1
            n = len(idx)
            rgb = [np.repeat(x, 3, -1) if n == 1 else np.concatenate([x, np.zeros_like(x[..., :1])], -1)
                   if n == 2 else x for x in stored]
            out, size = bc7_mips([np.concatenate([x, np.ones_like(x[..., :1])], -1) for x in rgb])
            out = [o[..., :n] for o in out]
        total += size
        for k, o in enumerate(out):
            low[k][..., idx] = from_storage(o, normal[idx])
    dec = [bilinear_up(low[0], *ref[k].shape[:2]) for k in range(d)] + low
    return dec[:2], total


def t0_layers(ts, ref: list[np.ndarray], res: int, n_comp: int):
    """T_0 of ⌈n_comp/4⌉ layers of principal components at ``res``, as the shipped ``--t0 pca``
    computes its one layer (`pca_init`): (per layer, its (H, W, 4) [0, 1] mips; the MLP dict holding
    the components' exact linear decoder). Unused channels of a last layer hold 0."""
    import torch

    from bcfpipe.config import ModelConfig
    from bcfpipe.formats.vocabulary import FeatureFormat
    from bcfpipe.model import neural as M
    from bcfpipe.texset import encoding
    from bcfpipe.train.feature_init import pca_init

    c = ts.num_channels
    n_layers = -(-n_comp // 4)
    mc = ModelConfig(resolutions=(res,) * 4, features=FeatureFormat.BC7)
    enc = encoding.encode_levels(ref, encoding.gains(ts.channels))
    mips = [torch.from_numpy(np.ascontiguousarray(m.transpose(2, 0, 1))) for m in enc]
    bias = math.log2(res / max(ts.width, ts.height))  # the shipped T_0's (M.lod_biases, layer 0)
    free = [[torch.zeros(4, res >> k, res >> k) for k in range(n)] for n in mc.mip_counts]
    mean = torch.from_numpy(enc[0].reshape(-1, c).mean(0))
    mlp = M.init_mlp(mc.n_inputs, mc.hidden, c, torch.Generator().manual_seed(0), torch.device("cpu"), mean)
    used = pca_init(mc, mips, (bias,) * 4, free, mlp, layers=tuple(range(n_layers)))
    assert used == min(n_comp, c), (used, n_comp, c)
    layers = [[(p.clamp(0.0, 255.0) / 255.0).permute(1, 2, 0).numpy().astype(np.float32) for p in free[i]]
              for i in range(n_layers)]
    return layers, {k: v.detach() for k, v in mlp.items()}


def t0_decode(ts, mlp, feats: list[np.ndarray]) -> np.ndarray:
    """Channels (H, W, c) of one T_0 level from its layers' (H, W, 4) values, through the linear
    decoder and the decoder's output clamp, back in the set's value domain."""
    import torch

    from bcfpipe.model.decoder import mlp_raw, output_ranges
    from bcfpipe.texset import encoding

    h, w = feats[0].shape[:2]
    x = np.zeros((h * w, mlp["w1"].shape[1]), np.float32)
    for i, f in enumerate(feats):
        x[:, 4 * i:4 * i + 4] = f.reshape(-1, 4)
    with torch.no_grad():
        y = (mlp_raw(mlp, torch.from_numpy(x)) * mlp["out_scale"] + mlp["out_bias"]).numpy()
    lo, hi = output_ranges(tuple(ch.kind for ch in ts.channels))
    y = np.clip(y, lo, hi).reshape(h, w, -1)
    return encoding.decode_levels([y], encoding.gains(ts.channels))[0]


def t0_rows(ts, ref: list[np.ndarray], res: int):
    """(label, GPU bytes, decoded reference mips 0 and 1, the same unencoded) per T_0 width at ``res``."""
    from bcfpipe.texset.baselines import bilinear_up, bc1_mips, bc7_mips

    c = ts.num_channels
    d = int(round(math.log2(max(ts.width, ts.height) / res)))
    ks = sorted({min(k, c) for k in (4, 8, 12)})
    plans = [(f"{k} PCs", k, ("bc7",) * -(-k // 4)) for k in ks]
    if c > 4:
        plans.insert(1, (f"{min(7, c)} PCs", 8, ("bc7", "bc1")))
    for label, k, fmts in plans:
        layers, mlp = t0_layers(ts, ref, res, k)
        size, dec = 0, []
        for fmt, lv in zip(fmts, layers):
            if fmt == "bc7":
                out, n = bc7_mips(lv)
            else:  # components 5-7 in BC1; the 8th (if any) held at its level mean
                out, n = bc1_mips([m[..., :3] for m in lv])
                out = [np.concatenate([o, np.full_like(o[..., :1], m[..., 3].mean())], -1) for o, m in zip(out, lv)]
            size += n
            dec.append(out)
        stored = " + ".join(f"{fmts.count(f)}×{f.upper()}" for f in dict.fromkeys(fmts))

        def ref01(levels: list[list[np.ndarray]]) -> list[np.ndarray]:
            top = t0_decode(ts, mlp, [lv[0] for lv in levels])
            if d == 0:
                return [top, t0_decode(ts, mlp, [lv[1] for lv in levels])]
            return [bilinear_up(top, *ref[0].shape[:2]), top]

        yield f"{label} at {res}², {stored}", size, ref01(dec), ref01(layers)


def widths(args) -> None:
    """Issue 52's oracle table (module docstring)."""
    from bcfpipe.texset.baselines import encode_texture_set_baseline
    from bcfpipe.texset.metrics import mse_per_mip, psnr_from_mse
    from bcfpipe.texset.texture_set import TextureSet, build_mip_chain, load_texture_set

    print(f"machine: {machine()}")
    print("| set | stored as | GPU MiB | mip 0 | mip 1 | unencoded mip 0 / 1 |")
    print("|---|---|---:|---:|---:|---|")
    for name in args.sets.split(","):
        t0 = time.perf_counter()
        ts = load_texture_set(specs(name))
        if args.crop:
            n = args.crop
            ts = TextureSet(np.ascontiguousarray(ts.data[:n, :n]), ts.channels, n, n)
        ref = build_mip_chain(ts.data)
        side = max(ts.width, ts.height)
        r = args.resolution or side // 2
        if r > side or r & (r - 1):
            raise SystemExit(f"--resolution {r}: {name} is {ts.width}x{ts.height}; "
                             f"R must be a power of two up to {side}")
        tag = f"{name} ({ts.num_channels} ch{f', {args.crop}² crop' if args.crop else ''})"

        def psnr(dec: list[np.ndarray]) -> list[float]:
            return [psnr_from_mse(m) for m in mse_per_mip(ref[:2], dec, ts.channels)]

        def row(label: str, size: int, dec, raw=None) -> None:
            p0, p1 = psnr(dec)
            extra = "/".join(f"{v:.1f}" for v in psnr(raw)) if raw is not None else ""
            print(f"| {tag} | {label} | {size / 2**20:.2f} | {p0:.1f} | {p1:.1f} | {extra} |", flush=True)

        bc, size = encode_texture_set_baseline(ts, "bc", r, ref_mips=ref)
        row(f"BC@R (R = {r})", size, bc[:2])
        q, size = bc7_quality_set(ts, r, ref)
        row(f"BC7 quality set at {r}", size, q)
        for res in (r, 2 * r):
            if res > side:
                print(f"<!-- {name}: T_0 at {res}² skipped: more texels than the "
                      f"{ts.width}x{ts.height} source -->", flush=True)
                continue
            for label, size, dec, raw in t0_rows(ts, ref, res):
                row(label, size, dec, raw)
        print(f"<!-- {name}: {time.perf_counter() - t0:.0f} s -->", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default=None, help="teapot,brick (default); with --widths teapot,brick,wood,bottle")
    ap.add_argument("--widths", action="store_true", help="issue 52's table: T_0 of 4, 8, 12 components at R and 2R")
    ap.add_argument("--crop", type=int, default=0, help="with --widths: the sets' top-left N² texels only")
    ap.add_argument("--resolution", type=int, default=0,
                    help="with --widths: R, BC@R's and T_0's resolution (default half the set's side: 1024 for 2048²)")
    ap.add_argument("--workers", type=int, default=None, help="cores for the encoders and torch (default all)")
    args = ap.parse_args()
    if args.workers:
        import torch

        from bcfpipe.texset.parallel import set_encode_workers

        torch.set_num_threads(args.workers)
        set_encode_workers(args.workers)
    if args.widths:
        args.sets = args.sets or "teapot,brick,wood,bottle"
        return widths(args)
    args.sets = args.sets or "teapot,brick"

    from bcfpipe.texset.baselines import bilinear_up, encode_texture_set_baseline
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
            report(label, codec, size, bilinear_up(rec, *ref[0].shape[:2]), rec)


if __name__ == "__main__":
    main()
