"""Shared bits of the benchmark scripts: the teapot texture set and machine description."""
from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# BCFPIPE_SCENES points elsewhere, e.g. at a copy carried to a lent GPU machine
SHARED = Path(os.environ.get("BCFPIPE_SCENES", REPO.parent / "shared" / "scenes"))
TEAPOT = SHARED / "usdwg_teapot" / "textures"


def teapot_specs():
    from bcfpipe.texset.texture_set import TextureSpec

    if not TEAPOT.is_dir():
        raise SystemExit(f"needs the shared scenes at {SHARED}")
    d, a = TEAPOT / "tea_set_01_diff_2k.jpg", TEAPOT / "tea_set_01_arm_2k.jpg"
    return [TextureSpec.parse(f"albedo={d}:rgb"), TextureSpec.parse(f"occlusion={a}:r"),
            TextureSpec.parse(f"roughness={a}:g"), TextureSpec.parse(f"metallic={a}:b")]


def machine() -> str:
    """CPU model, cores, and the GPU torch sees, for the record in docs/benchmarks.md."""
    from bcfpipe.bench.run import machine as record

    m = record()
    return f"{m['cpu']}, {m['cores']} cores, torch {m['torch']}, {m['gpu'] or 'no GPU'}"
