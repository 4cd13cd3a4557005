"""Issue 58: the classic encoders' presets, seconds against PSNR, for `config.ENCODE_PRESETS`.

quicktex's BC1 at each level and ISPC's BC7 at each alpha profile and `baselines.BC7_PROFILES`'s
``quick`` (against ``basic``, the profile BC7 ships with above `draft`), on a 1024² crop of the
teapot's, the brick's and the wood's colour (BC7:
with the set's roughness as alpha), one thread, level 0 only. Prints seconds and PSNR over the
crop's channels as 8-bit values.

  python benchmarks/bench_classic_presets.py
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SHARED, machine  # noqa: E402

SETS = {"teapot": (SHARED / "usdwg_teapot/textures/tea_set_01_diff_2k.jpg", SHARED / "usdwg_teapot/textures/tea_set_01_arm_2k.jpg"),
        "brick": (SHARED / "materialx_texture_sets/brick/brick_base_gray.jpg",
                  SHARED / "materialx_texture_sets/brick/brick_roughness.jpg"),
        "wood": (SHARED / "materialx_texture_sets/wood/wood_color.jpg",
                 SHARED / "materialx_texture_sets/wood/wood_roughness.jpg")}


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = ((a.astype(np.float64) - b) ** 2).mean() / 255 ** 2
    return 10 * np.log10(1 / mse)


def main() -> None:
    import ispc_texcomp as ispc
    import quicktex
    import texture2ddecoder as t2d
    from quicktex.s3tc.bc1 import BC1Decoder, BC1Encoder

    from bcfpipe.texset.baselines import bc7_settings

    print(f"machine: {machine()}", flush=True)
    shipped = bc7_settings("basic")
    for name, (colour, rough) in SETS.items():
        rgb = np.asarray(Image.open(colour).convert("RGB"))[:1024, :1024]
        rgba = np.ascontiguousarray(np.concatenate([rgb, np.asarray(Image.open(rough).convert("RGB"))[:1024, :1024, 1:2]], -1))
        h, w = rgb.shape[:2]
        tex = quicktex.RawTexture.frombytes(np.concatenate([rgb, np.full((h, w, 1), 255, np.uint8)], -1).tobytes(), w, h)
        best = None
        for level in (18, 17, 16, 15, 14, 13, 12, 10, 8):
            t = time.perf_counter()
            b = BC1Encoder(level).encode(tex)
            dt = time.perf_counter() - t
            d = np.frombuffer(BC1Decoder().decode(b).tobytes(), np.uint8).reshape(h, w, 4)[..., :3]
            p = psnr(d, rgb)
            best = p if best is None else best
            print(f"{name:7s} BC1 quicktex level {level:2d}: {dt:5.2f} s, {p:.3f} dB ({p - best:+.3f})", flush=True)
        best = None
        for profile in ("shipped", "quick", "alpha_slow", "alpha_basic", "alpha_fast", "alpha_veryfast"):
            st = (shipped if profile == "shipped" else bc7_settings(profile) if profile == "quick"
                  else ispc.BC7EncSettings.from_profile(profile))
            t = time.perf_counter()
            b = ispc.compress_blocks_bc7(ispc.RGBASurface(rgba.tobytes(), w, h), st)
            dt = time.perf_counter() - t
            d = np.frombuffer(t2d.decode_bc7(bytes(b), w, h), np.uint8).reshape(h, w, 4)[..., [2, 1, 0, 3]]
            p = psnr(d, rgba)
            best = p if best is None else best
            print(f"{name:7s} BC7 ISPC {profile:14s}: {dt:5.2f} s, {p:.3f} dB ({p - best:+.3f})", flush=True)


if __name__ == "__main__":
    main()
