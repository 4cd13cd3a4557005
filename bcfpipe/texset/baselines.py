"""Classic block-compression baselines (BC1/BC4/BC5, ASTC) evaluated through the same metric code.

Each codec function takes a mip chain of (H, W, c) float arrays in [0, 1] (stored values),
quantises to 8 bits as a texture exporter would, encodes and decodes every mip, and returns the
decoded mips (float32, same shapes) with the compressed size in bytes (block payload only, no
container headers).

* BC6H (UF16, for a colour group beyond 1 whose source is float): ISPC's encoder (`BC6H_PROFILE`),
  decoded by bcfpipe.bc6h; it stores the source's linear values as half floats (an HDR set's
  normalised values times its value_scale), not [0, 1]. 16 bytes / block.
* BC1 / BC4 / BC5: encoded by quicktex, decoded by bcfpipe's own decoders (`bcfpipe.formats.s3tc`,
  as every BC format bcfpipe ships; quicktex's and texture2ddecoder's are the tests' oracles)
  (``BC1Encoder(18)``, its slowest and best preset, four-colour mode; a
  layout's encodes take the quality preset's level, `config.ENCODE_PRESETS`;
  ``BC4Encoder``, ``BC5Encoder``). Levels whose sides are not multiples of 4 (including 2x2, 1x1) are padded to
  whole 4x4 blocks by edge replication and cropped after decoding. BC1 = BC4 = 8 bytes / block,
  BC5 = 16 bytes / block.
* ASTC: the ``astcenc`` CLI in LDR-linear mode, one ``-tl`` (compress + decompress, identical to
  ``-cl`` then ``-dl``, which run instead when the caller wants the blocks) process per mip through
  temporary 8-bit PNGs, ``-thorough`` by default. 16 bytes per block, ceil(w/bw) * ceil(h/bh) blocks.
* BC7 (the quality set's colour and packed textures): ISPC (`BC7_SETTINGS`), 16 bytes / block.

`encode_texture_set_baseline` packs a `TextureSet` into the textures an engine would ship and
maps the result back to the reference mips; see its docstring for the resolution handling.
"""
from __future__ import annotations

import math
import os
import shutil
import subprocess
import tempfile
from typing import Sequence

import numpy as np
import xxhash

from bcfpipe.formats.bcn import decode_levels
from bcfpipe.formats.bcn import ClassicFormat
from bcfpipe.texset.blocks import store as blocks_store
from bcfpipe.texset.normals import slope_normal, slope_scale, slope_texels
from bcfpipe.texset.parallel import quicktex_level
from bcfpipe.texset.parallel import threaded_bands
from bcfpipe.texset.texture_set import TextureSet, build_mip_chain

__all__ = ["from_storage", "encode_texture", "bilinear_up", "parse_block", "bc1_mips", "bc4_mips", "bc5_mips", "astc_mips", "encode_texture_set_baseline",
           "encode_texture_set_shipped", "astcenc_path",
           "pack_texture_set", "CODECS", "BC7_QUALITY", "USD", "NORMAL_SLOPE", "slope_mips", "BC1_LEVEL", "bc7_mips", "bc7_settings", "BC7_PROFILES", "bc6h_mips", "is_hdr_color"]

CODECS = ("bc", "astc")
# The BC7 quality set (issue 52): BC@R ('bc') with every BC1 texture, a colour or a packed file, in BC7;
# BC5 normals, BC4 lone scalars and BC6H kept. What quality-focused pipelines ship: a second set to
# weigh neural materials against (bcfpipe.layout.classic.bc7_quality_set is the layout's).
BC7_QUALITY = "bc7"
# What a layout ships for USD (issue 57): 'bc' with a normal map as BC5 of its slopes (x / z, y / z) / m
# (bcfpipe.texset.normals), BC5's bytes: a UsdUVTexture cannot rebuild z, so BC5's x, y would reach a
# UsdPreviewSurface as normalize(x, y, 1); it reads (s_x, s_y, 1), whose direction is (x, y, z).
# bcfpipe.layout.classic's groups are these.
USD = "usd"
NORMAL_SLOPE = "bc5s"  # pack_texture_set's format of such a normal: BC5 blocks of clip(s / m) / 2 + 1 / 2
BC1_LEVEL = 18  # quicktex presets run 0..18


def _to_u8_rgba(img: np.ndarray) -> np.ndarray:
    """(H, W, c<=4) floats in [0, 1] -> (H, W, 4) uint8, missing channels 0, alpha 255."""
    h, w, c = img.shape
    out = np.zeros((h, w, 4), np.uint8)
    out[..., 3] = 255
    out[..., :c] = np.rint(np.clip(img, 0.0, 1.0) * 255.0).astype(np.uint8)
    return out


def _pad4(img: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    ph, pw = -h % 4, -w % 4
    return np.pad(img, ((0, ph), (0, pw), (0, 0)), mode="edge") if ph or pw else img


def _check_mips(mips: Sequence[np.ndarray], channels: int, what: str) -> None:
    if not mips:
        raise ValueError(f"{what}: no mips given")
    for k, m in enumerate(mips):
        if np.ndim(m) != 3 or np.shape(m)[2] != channels:
            raise ValueError(f"{what}: mip {k} has shape {np.shape(m)}, expected (H, W, {channels})")


def _cached_levels(tag: str, mips: Sequence[np.ndarray], texels=None) -> tuple[object, str, list[np.ndarray] | None]:
    """(the build's blocks cache or None, the key of ``mips``' texels under encoder ``tag``, the
    levels' blocks recorded under it or None). The texels keyed are what the encoder reads:
    ``texels(mip)``, by default the padded 8-bit RGBA."""
    cache = blocks_store()
    if cache is None:
        return None, "", None
    digest = xxhash.xxh3_128(tag.encode())
    for m in mips:  # one mip's padded texels at a time, as the encode: no 8K chain held twice
        px = texels(m) if texels is not None else _pad4(_to_u8_rgba(np.asarray(m)))
        digest.update(repr(px.shape).encode())
        digest.update(px.tobytes())
    key = digest.hexdigest()
    return cache, key, cache.get(key, len(mips))


def _quicktex_roundtrip(mips: Sequence[np.ndarray], fmt, tag: str, channels: int, block_bytes: int,
                        blocks: list | None = None) -> tuple[list[np.ndarray], int]:
    """Encode each mip with quicktex (the encoder and settings ``tag`` names) and decode it as ``fmt``
    by bcfpipe's own decoder (`bcfpipe.formats.bcn.decode_levels`); with ``blocks`` also append each level's (block bytes as an
    (n, block_bytes) uint8 array, width, height), ready for a GPU upload. Inside a build with a
    cache (bcfpipe.texset.blocks), blocks already encoded from the same texels by the same encoder
    (``tag`` names it and its settings) are read back instead of encoded again."""
    import quicktex  # lazy: start-up

    cache, key, levels = _cached_levels(f"{tag}|quicktex {quicktex.__version__}|{block_bytes}", mips)
    encoded = []
    decoded, size = [], 0
    for k, m in enumerate(mips):
        h, w = m.shape[:2]
        px = _pad4(_to_u8_rgba(np.asarray(m)))
        if levels is None:
            b = quicktex_level(tag, px, block_bytes)  # in bands over the job's cores: the same bytes
            encoded.append(b)
        else:
            b = levels[k]
        size += b.nbytes
        if blocks is not None:
            blocks.append((b, w, h))
        decoded.append(decode_levels(fmt, [(b, w, h)])[0][..., :channels])
    if cache is not None and levels is None:
        cache.put(key, encoded)
    return decoded, size


def bc1_mips(mips_rgb: Sequence[np.ndarray], level: int = BC1_LEVEL,
             blocks: list | None = None) -> tuple[list[np.ndarray], int]:
    """BC1-encode and decode every (H, W, 3) mip; returns (decoded mips, bytes)."""
    _check_mips(mips_rgb, 3, "bc1")
    return _quicktex_roundtrip(mips_rgb, ClassicFormat.BC1, f"bc1 level {level}", 3, 8, blocks)


# ISPC's ``alpha_basic`` profile (ispc_texcomp.h, GetProfile_alpha_basic): every mode group (0/2,
# 1/3/7, 4/5, 6) but mode 2, fast skips of 12/8/8 partitions for modes 1/3/7, 2 refinements. On the
# sample scene's sets it is within 0.03 dB of alpha_slow (every mode, more refinement) at a third of
# the time (benchmarks/bound_classic_bc7.py).
# ``quick`` is ISPC's alpha_veryfast (no partition search for modes 1/3, 4 for mode 7) with every
# rotation of modes 4/5 that alpha_basic tries: on 1024² crops of the teapot's, brick's and wood's
# colour with their roughness as alpha, 0.64x alpha_basic's time within 0.005 dB; alpha_veryfast's
# one rotation loses 0.17 dB on the teapot (benchmarks/bench_classic_presets.py).
# ``alpha_modes`` is ``basic`` in the modes that store alpha (4-7: ISPC's modes 0/2 off, modes 1 and 3
# searching no partition), for four live channels, where the opaque modes never win: a T_0 of
# principal components at 1k on the teapot, brick and wood gives basic's very blocks, on the water
# bottle all but 4 of 87,381 (modes 1 and 3), in half the time (benchmarks/bench_t0_encode.py).
# One-subset modes alone (4-6) take 0.28x but lose 0.3-1.4 dB there: mode 7 holds 10-45 % of the blocks.
BC7_PROFILES: dict[str, dict] = {
    "basic": dict(modes=(True, True, True, True), refine=2, skip_mode2=True, fast_skip=(12, 8, 8), mode45_channel0=0),
    "quick": dict(modes=(True, True, True, True), refine=2, skip_mode2=True, fast_skip=(0, 0, 4), mode45_channel0=0),
    "alpha_modes": dict(modes=(False, True, True, True), refine=2, skip_mode2=True, fast_skip=(0, 0, 8),
                        mode45_channel0=0),
}
BC7_SETTINGS = BC7_PROFILES["basic"]  # what the BC7 quality set, a PCA T_0 and the baselines encode with


def bc7_settings(profile: str = "basic"):
    """ISPC's BC7 settings of `BC7_PROFILES` ``profile``."""
    import ispc_texcomp as ispc  # lazy: start-up

    s = BC7_PROFILES[profile]
    return ispc.BC7EncSettings(list(s["modes"]), [s["refine"]] * 8, s["skip_mode2"], *s["fast_skip"],
                               s["mode45_channel0"], s["refine"], 4)


def _ispc_bc7_levels(mips_rgba: Sequence[np.ndarray], profile: str = "basic") -> list[np.ndarray]:
    """(H, W, 4) [0, 1] mips -> each level's BC7 blocks, (n, 16) uint8, row-major, by ISPC at
    ``profile``, in bands over the job's encode workers (the encoder releases the GIL:
    bcfpipe.texset.parallel)."""
    import ispc_texcomp as ispc  # lazy: start-up

    settings = bc7_settings(profile)

    def band(px: np.ndarray) -> bytes:
        return ispc.compress_blocks_bc7(ispc.RGBASurface(np.ascontiguousarray(px).tobytes(), px.shape[1],
                                                         px.shape[0]), settings)

    return [threaded_bands(band, _pad4(_to_u8_rgba(np.asarray(m))), 16) for m in mips_rgba]


def bc7_mips(mips_rgba: Sequence[np.ndarray], blocks: list | None = None,
             profile: str = "basic") -> tuple[list[np.ndarray], int]:
    """BC7-encode (ISPC, `BC7_PROFILES` ``profile``) and decode (bcfpipe.bc7) every (H, W, 4)
    mip; returns (decoded mips, bytes). With ``blocks``, each level's (blocks, w, h) is appended. In
    a build with a cache the blocks are kept as BC1/BC4/BC5's are."""
    import ispc_texcomp as ispc  # lazy: start-up

    _check_mips(mips_rgba, 4, "bc7")
    return _ispc_round_trip(f"bc7 ispc {ispc.version}|{sorted(BC7_PROFILES[profile].items())}", mips_rgba,
                            lambda m: _ispc_bc7_levels(m, profile), ClassicFormat.BC7, blocks)


def _ispc_round_trip(tag: str, mips: Sequence[np.ndarray], encode_levels, fmt, blocks: list | None,
                     texels=None) -> tuple[list[np.ndarray], int]:
    """Encode ``mips`` with ``encode_levels`` (or take the blocks the build's cache holds under
    ``tag``), decode them as ``fmt``; returns (decoded mips, bytes). With ``blocks``, each level's
    (blocks, w, h) is appended."""
    cache, key, levels = _cached_levels(tag, mips, texels)
    fresh = levels is None
    if fresh:
        levels = encode_levels(mips)
    shipped = [(b, m.shape[1], m.shape[0]) for m, b in zip(mips, levels)]
    if blocks is not None:
        blocks.extend(shipped)
    decoded = decode_levels(fmt, shipped)
    if cache is not None and fresh:
        cache.put(key, levels)
    return decoded, sum(b.nbytes for b in levels)


# ISPC's ``basic`` BC6H profile (ispc_texcomp.h, GetProfile_bc6h_basic): every mode, 2 refinements, no slow
# search. On the HDR ramp (benchmarks/bench_hdr.py, 512²) its mean |log1p error| is 0.0040 against
# ``veryslow``'s 0.0037, in a ninth of the time (0.12 s against 1.09 s on one thread; a 2048² chain
# about 2.5 s).
BC6H_PROFILE = "basic"


def _to_half_rgba(img: np.ndarray) -> np.ndarray:
    """(H, W, c<=3) non-negative floats -> (H, W, 4) float16 padded to whole blocks, missing channels 0,
    alpha 1: what ISPC's BC6H encoder reads. Values are clipped to [0, 65504] (UF16 holds no less)."""
    h, w, c = img.shape
    out = np.zeros((h, w, 4), np.float16)
    out[..., 3] = 1.0
    out[..., :c] = np.clip(img, 0.0, 65504.0).astype(np.float16)
    return _pad4(out)


def _ispc_bc6h_levels(mips: Sequence[np.ndarray]) -> list[np.ndarray]:
    """(H, W, c<=3) mips of linear values -> each level's BC6H_UF16 blocks, (n, 16) uint8, row-major,
    by ISPC, in bands over the job's encode workers (the encoder releases the GIL)."""
    import ispc_texcomp as ispc  # lazy: start-up

    settings = ispc.BC6HEncSettings.from_profile(BC6H_PROFILE)

    def band(px: np.ndarray) -> bytes:
        px = np.ascontiguousarray(px)
        return ispc.compress_blocks_bc6h(ispc.RGBASurface(px.tobytes(), px.shape[1], px.shape[0], px.shape[1] * 8),
                                         settings)

    return [threaded_bands(band, _to_half_rgba(np.asarray(m)), 16) for m in mips]


def bc6h_mips(mips_rgb: Sequence[np.ndarray], blocks: list | None = None) -> tuple[list[np.ndarray], int]:
    """BC6H_UF16-encode (ISPC, `BC6H_PROFILE`) and decode (bcfpipe.bc6h) every (H, W, c<=3) mip of
    linear non-negative values (not [0, 1]: HDR as it is); returns (decoded mips with c channels,
    bytes). With ``blocks``, each level's (blocks, w, h) is appended; in a build with a cache the
    blocks are kept, keyed by the half-float texels the encoder reads."""
    import ispc_texcomp as ispc  # lazy: start-up

    if not mips_rgb or any(np.ndim(m) != 3 or not 1 <= np.shape(m)[2] <= 3 for m in mips_rgb):
        raise ValueError(f"bc6h: mips must be (H, W, 1..3), got {[np.shape(m) for m in mips_rgb]}")
    c = mips_rgb[0].shape[2]
    decoded, size = _ispc_round_trip(f"bc6h uf16 ispc {ispc.version} {BC6H_PROFILE}", mips_rgb, _ispc_bc6h_levels,
                                     ClassicFormat.BC6H, blocks, lambda m: _to_half_rgba(np.asarray(m)))
    return [d[..., :c] for d in decoded], size


def bc5_mips(mips_xy: Sequence[np.ndarray], blocks: list | None = None) -> tuple[list[np.ndarray], int]:
    """BC5-encode and decode every (H, W, 2) mip of [0, 1] data; returns (decoded mips, bytes)."""
    _check_mips(mips_xy, 2, "bc5")
    return _quicktex_roundtrip(mips_xy, ClassicFormat.BC5, "bc5 channels 0 1", 2, 16, blocks)


def slope_mips(mips_xy: Sequence[np.ndarray], blocks: list | None = None,
               m: float | None = None) -> tuple[list[np.ndarray], float, int]:
    """A normal map's (H, W, 2) set-value mips as `NORMAL_SLOPE` (issue 57): m from level 0
    (`normals.slope_scale`) unless given (a sample of blocks takes the whole level's), every mip's
    slopes clip(s / m) / 2 + 1 / 2 in BC5 (quicktex, as BC@R's normal); (each mip decoded as
    (s_x, s_y, 1) normalised, (H, W, 3); m; bytes)."""
    m = slope_scale(mips_xy[0]) if m is None else m
    out, size = bc5_mips([slope_texels(x, m) for x in mips_xy], blocks)
    return [slope_normal(o, m) for o in out], m, size


def bc4_mips(mips_x: Sequence[np.ndarray], blocks: list | None = None) -> tuple[list[np.ndarray], int]:
    """BC4-encode and decode every (H, W, 1) mip of [0, 1] data; returns (decoded mips, bytes)."""
    _check_mips(mips_x, 1, "bc4")
    return _quicktex_roundtrip(mips_x, ClassicFormat.BC4, "bc4 channel 0", 1, 8, blocks)


def astcenc_path() -> str | None:
    """The astcenc executable ($ASTCENC, else the first astcenc* on PATH), or None."""
    env = os.environ.get("ASTCENC")
    if env:
        return env
    for name in ("astcenc", "astcenc-avx2", "astcenc-sse4.1", "astcenc-sse2", "astcenc-neon"):
        p = shutil.which(name)
        if p:
            return p
    return None


ASTC_HEADER_BYTES = 16  # a .astc file: magic, block dimensions, image size; then the blocks


def _astcenc(exe: str, src: str, dst: str, block: str, preset: str, threads: int, keep: bool, what: str) -> None:
    """``src`` PNG -> ``dst`` PNG through ASTC: one ``-tl`` run, or with ``keep`` ``-cl`` to
    ``dst``.astc then ``-dl`` from it."""
    opts = [block, preset, "-silent", "-j", str(threads)]
    runs = ([[exe, "-cl", src, dst + ".astc", *opts], [exe, "-dl", dst + ".astc", dst, "-silent"]] if keep
            else [[exe, "-tl", src, dst, *opts]])
    for cmd in runs:
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            raise RuntimeError(f"astcenc failed on {what}: {(res.stderr or res.stdout).strip()[-300:]}")
    if not os.path.isfile(dst):
        raise RuntimeError(f"astcenc failed on {what}: it wrote no {os.path.basename(dst)}")


def parse_block(block: str) -> tuple[int, int]:
    try:
        bw, bh = (int(v) for v in block.lower().split("x"))
    except ValueError:
        raise ValueError(f"ASTC block must look like '12x12', got {block!r}") from None
    if not (4 <= bw <= 12 and 4 <= bh <= 12):
        raise ValueError(f"ASTC 2D block sides must be in 4..12, got {block!r}")
    return bw, bh


def astc_mips(mips_rgb: Sequence[np.ndarray], block: str = "12x12", preset: str = "-thorough",
              threads: int | None = None, tmp_dir: str | None = None,
              blocks: list | None = None) -> tuple[list[np.ndarray], int]:
    """ASTC (LDR linear) encode and decode every (H, W, 3) mip with astcenc; (decoded, bytes).
    The PNGs astcenc reads and writes live in a temporary folder under ``tmp_dir``. With
    ``blocks``, each level's (blocks as an (n, 16) uint8 array, w, h) is appended: astcenc then
    compresses to a .astc file (``-cl``) and decompresses it (``-dl``), the same texels as ``-tl``."""
    import OpenImageIO as oiio  # lazy: start-up

    _check_mips(mips_rgb, 3, "astc")
    bw, bh = parse_block(block)
    exe = astcenc_path()
    if exe is None:
        raise RuntimeError("astcenc not found: install it (e.g. apt-get install astcenc) or set $ASTCENC")
    threads = threads or min(os.cpu_count() or 1, 8)
    decoded, size = [], 0
    with tempfile.TemporaryDirectory(prefix="bcf-astc-", dir=tmp_dir) as tmp:
        for k, m in enumerate(mips_rgb):
            h, w = m.shape[:2]
            src, dst = os.path.join(tmp, f"in{k}.png"), os.path.join(tmp, f"out{k}.png")
            px = np.ascontiguousarray(_to_u8_rgba(np.asarray(m))[..., :3])
            buf = oiio.ImageBuf(oiio.ImageSpec(w, h, 3, oiio.UINT8))
            buf.set_pixels(oiio.ROI(0, w, 0, h, 0, 1, 0, 3), px)
            if not buf.write(src):
                raise RuntimeError(f"cannot write {src}: {buf.geterror()}")
            _astcenc(exe, src, dst, f"{bw}x{bh}", preset, threads, blocks is not None, f"mip {k} ({w}x{h})")
            if blocks is not None:
                data = np.fromfile(dst + ".astc", np.uint8)[ASTC_HEADER_BYTES:]
                blocks.append((data.reshape(-1, 16), w, h))
            out = oiio.ImageBuf(dst).get_pixels(oiio.FLOAT)
            decoded.append(np.asarray(out, np.float32).reshape(h, w, -1)[..., :3].copy())
            size += math.ceil(w / bw) * math.ceil(h / bh) * 16
    return decoded, size


# --------------------------------------------------------------------------------------------
# texture sets


def pack_texture_set(ts: TextureSet, codec: str) -> list[tuple[str, list[int]]]:
    """How an engine would pack the set's channels into textures: [(format, channel indices)].

    Colour groups (albedo, emissiveColor): one 3-channel texture each; with 'bc', a colour group
    beyond 1 from a float file (`is_hdr_color`) is BC6H_UF16 of its linear values, as engines ship
    HDR (never BC1 or a repack: 8 bits of a 0..3,000 range lose every value below 12). Normal x, y: one BC5
    texture ('bc') or an ASTC texture with b = 0 ('astc'). Scalar and generic channels ('bc'):
    those that share a source file with other scalars stay packed as that file packs them
    (ARM-style, BC1), a scalar alone in its file gets its own BC4 texture. ('astc'): all of them,
    in set order, packed 3 per 3-channel texture; a last texture with 1 channel replicates it into
    r, g, b (a grey image), one with 2 leaves b = 0. (`BC7_QUALITY`): as 'bc', every BC1 texture
    in BC7. (`USD`): as 'bc', a normal map as BC5 of its slopes (`NORMAL_SLOPE`).
    """
    if codec == BC7_QUALITY:
        return [("bc7" if fmt == "bc1" else fmt, idx) for fmt, idx in pack_texture_set(ts, "bc")]
    if codec == USD:
        return [(NORMAL_SLOPE if fmt == "bc5" else fmt, idx) for fmt, idx in pack_texture_set(ts, "bc")]
    if codec not in CODECS:
        raise ValueError(f"codec must be one of {CODECS}, got {codec!r}")
    rgb = "bc1" if codec == "bc" else "astc"
    textures: list[tuple[str, list[int]]] = []
    scalars: list[int] = []
    held = _vector_textures(ts) if codec == "bc" else {}
    done: set[int] = set()
    for sem, idx in ts.groups().items():
        for c in idx:  # a vector a UsdUVTexture reads: its texture where its first channel comes
            if c in held and c not in done:
                textures.append(held[c])
                done.update(held[c][1])
        if done.intersection(idx):
            scalars.extend(c for c in idx if c not in done)
            continue
        kind = ts.kind_of(sem)
        if codec == "bc" and is_hdr_color(ts, idx):
            textures.append(("bc6h", idx))
        elif kind == "color" and len(idx) == 3:
            textures.append((rgb, idx))
        elif kind == "normal":
            textures.append(("bc5" if codec == "bc" else "astc", idx))
        else:
            scalars.extend(idx)
    if codec == "bc":
        by_file: dict[str, list[int]] = {}
        for i in scalars:
            by_file.setdefault(ts.channels[i].source, []).append(i)
        alone = [i for i in scalars if len(by_file[ts.channels[i].source]) == 1]
        scalars = [i for i in scalars if i not in alone]
        for i in range(0, len(scalars), 3):
            textures.append((rgb, scalars[i:i + 3]))
        textures.extend(("bc4", [i]) for i in alone)
        return textures
    for i in range(0, len(scalars), 3):
        textures.append((rgb, scalars[i:i + 3]))
    return textures


def _vector_textures(ts: TextureSet) -> dict[int, tuple[str, list[int]]]:
    """The BC1 (or BC6H) texture of each of ``ts.vectors`` (a colour a UsdUVTexture reads through
    rgb, its slots' channels, a channel twice where the source repeats it), by each of its channels;
    a vector one of whose channels an earlier one holds is left out (its input keeps its source)."""
    out: dict[int, tuple[str, list[int]]] = {}
    for _, chans in ts.vectors:
        if any(c in out for c in chans):
            continue
        tex = ("bc6h" if is_hdr_color(ts, sorted(set(chans))) else "bc1", list(chans))
        out.update({c: tex for c in chans})
    return out


def is_hdr_color(ts: TextureSet, idx: Sequence[int]) -> bool:
    """Whether channels ``idx`` are a colour group with a channel beyond 1 from a float file: those
    learnt in a log domain (``Channel.log_gain`` > 0, bcfpipe.texset.encoding), non-negative."""
    return all(ts.channels[i].kind == "color" for i in idx) and any(ts.channels[i].log_gain > 0 for i in idx)


def hdr_value_map(ts: TextureSet, idx: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """(value_scale, value_bias) of channels ``idx``: source value = set value * scale + bias, what
    a BC6H group stores."""
    return (np.array([ts.channels[i].value_scale for i in idx], np.float32),
            np.array([ts.channels[i].value_bias for i in idx], np.float32))


def _to_storage(x: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Set values -> stored [0, 1] values (normals v -> (v + 1) / 2)."""
    return np.where(normal, (x + 1.0) * 0.5, x)


def from_storage(x: np.ndarray, normal: np.ndarray) -> np.ndarray:
    return np.where(normal, x * 2.0 - 1.0, x).astype(np.float32)


def bilinear_up(img: np.ndarray, height: int, width: int) -> np.ndarray:
    """Bilinear magnification (texel-centre aligned, clamp to edge), as a GPU sampler would."""
    import torch  # lazy: start-up

    t = torch.from_numpy(np.ascontiguousarray(np.moveaxis(img, -1, 0)))[None].double()
    up = torch.nn.functional.interpolate(t, size=(height, width), mode="bilinear", align_corners=False)
    return np.moveaxis(up[0].numpy(), 0, -1).astype(np.float32)


def encode_texture(ts: TextureSet, fmt: str, idx: list[int], src: Sequence[np.ndarray], levels: list | None,
                    astc, bc1_level: int = BC1_LEVEL) -> tuple[list[np.ndarray], int]:
    """One texture of `pack_texture_set` (``fmt``, channels ``idx``) encoded and decoded at every mip
    of ``src`` (set values); (its decoded stored values per mip, bytes). BC1, BC7 and ASTC (``astc(rgb
    mips, blocks)``) read RGB: a lone channel replicated, two with b = 0; BC7's alpha is 1."""
    normal = np.array([ts.channels[i].kind == "normal" for i in idx])
    if fmt == "bc6h":  # linear source values, as the source file held them
        scale, bias = hdr_value_map(ts, idx)
        out, size = bc6h_mips([m[..., idx] * scale + bias for m in src], levels)
        return [(o - bias) / scale for o in out], size
    if fmt == NORMAL_SLOPE:  # decoded as a UsdPreviewSurface reads it: (s_x, s_y, 1) normalised
        normals, _, size = slope_mips([m[..., idx] for m in src], levels)
        return [(n[..., :2] + 1.0) * 0.5 for n in normals], size
    stored = [_to_storage(m[..., idx], normal) for m in src]
    if fmt == "bc5":
        return bc5_mips(stored, levels)
    if fmt == "bc4":
        return bc4_mips(stored, levels)
    n = len(idx)
    rgb = [np.repeat(s, 3, axis=-1) if n == 1 else
           np.concatenate([s, np.zeros_like(s[..., :1])], axis=-1) if n == 2 else s for s in stored]
    if fmt == "bc1":
        out, size = bc1_mips(rgb, bc1_level, blocks=levels)
    elif fmt == "bc7":
        out, size = bc7_mips([np.concatenate([x, np.ones_like(x[..., :1])], axis=-1) for x in rgb], levels)
    else:
        out, size = astc(rgb, levels)
    return [o[..., :n] for o in out], size


def encode_texture_set_baseline(ts: TextureSet, codec: str, resolution: int | None = None, *,
                                ref_mips: Sequence[np.ndarray] | None = None, astc_block: str = "12x12",
                                astc_preset: str = "-thorough", textures: list | None = None,
                                tmp_dir: str | None = None) -> tuple[list[np.ndarray], int]:
    """Compress `ts` with a classic codec; returns (decoded mips in the reference's shapes, bytes).

    `codec` 'bc': BC1 for colour and packed scalar textures, BC4 for a lone scalar, BC5 for
    normals (the paper's BC setup), BC6H_UF16 for an HDR colour group; `BC7_QUALITY`: the same
    with BC7 for BC1; 'astc': ASTC `astc_block` for every texture. Packing: `pack_texture_set`.

    Resolution: `resolution` (a power of two, default the set's larger side) caps the larger side
    of the shipped textures. When it is smaller than the set by 2^d, the baseline's level 0 is the
    reference's (box-filtered) mip d and its mip k is compared against reference mip k + d; the d
    top reference mips it lacks are its decoded level 0 magnified bilinearly (what a GPU shows when
    it samples a lower-resolution texture there). No upsampling of the source ever happens.
    `ref_mips` may pass a precomputed `build_mip_chain(ts.data)`. With ``textures``, each shipped
    texture is appended as (format, channel indices, [(blocks, w, h) per level]) so that a renderer
    can sample the very blocks that were measured (bcfpipe.bench.decode_cost), or their bytes on
    disk be counted (an ASTC level's blocks are 16 bytes each, as a .astc file holds them).
    """
    ref = list(ref_mips) if ref_mips is not None else build_mip_chain(ts.data)
    shipped, total = encode_texture_set_shipped(ts, codec, resolution, ref_mips=ref, astc_block=astc_block,
                                                astc_preset=astc_preset, textures=textures, tmp_dir=tmp_dir)
    d = sum(m is None for m in shipped)
    return [bilinear_up(shipped[d], *ref[k].shape[:2]) for k in range(d)] + shipped[d:], total


def encode_texture_set_shipped(ts: TextureSet, codec: str, resolution: int | None = None, *,
                               ref_mips: Sequence[np.ndarray] | None = None, astc_block: str = "12x12",
                               astc_preset: str = "-thorough", textures: list | None = None,
                               tmp_dir: str | None = None) -> tuple[list[np.ndarray | None], int]:
    """`encode_texture_set_baseline` without the magnification: the d reference mips above the
    shipped resolution are None, for a caller that magnifies level 0 its own way
    (bcfpipe.layout.classic, with the material's addressing)."""
    if codec not in (*CODECS, BC7_QUALITY, USD):
        raise ValueError(f"codec must be one of {(*CODECS, BC7_QUALITY, USD)}, got {codec!r}")
    ref = list(ref_mips) if ref_mips is not None else build_mip_chain(ts.data)
    side = max(ts.width, ts.height)
    res = side if resolution is None else int(resolution)
    if res < 1 or res & (res - 1):
        raise ValueError(f"baseline resolution must be a power of two, got {resolution}")
    d = max(0, int(round(math.log2(side / res))))
    d = min(d, len(ref) - 1)
    src = ref[d:]

    normal = np.array([ch.kind == "normal" for ch in ts.channels])
    dec_low = [np.zeros_like(m, dtype=np.float32) for m in src]
    total = 0
    for fmt, idx in pack_texture_set(ts, codec):
        levels: list | None = [] if textures is not None else None
        out, size = encode_texture(ts, fmt, idx, src, levels,
                                    lambda rgb, blocks: astc_mips(rgb, astc_block, astc_preset, tmp_dir=tmp_dir,
                                                                  blocks=blocks))
        if levels is not None:
            textures.append((fmt, list(idx), levels))
        total += size
        once = list(dict.fromkeys(idx))  # a channel stored twice (a vector's repeat) is measured at its first slot
        first = [list(idx).index(c) for c in once]
        for k, o in enumerate(out):
            dec_low[k][..., once] = from_storage(o[..., first], normal[once])

    return [None] * d + dec_low, total
