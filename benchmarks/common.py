"""Shared bits of the benchmark scripts (issue 59: one copy here, not one per script): where the
shared scenes are and the texture sets the scripts train on, the machine description, the options
most scripts take, `bcfpipe` as a timed child process, the cells of a per-mip PSNR table and the
--json record."""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# BCFPIPE_SCENES points elsewhere, e.g. at a copy carried to a lent GPU machine
SHARED = Path(os.environ.get("BCFPIPE_SCENES", REPO.parent / "shared" / "scenes"))
TEAPOT = SHARED / "usdwg_teapot" / "textures"
MX = SHARED / "materialx_texture_sets"
BOTTLE = SHARED / "gltf_water_bottle"
_ORM = BOTTLE / "WaterBottle_occlusionRoughnessMetallic.png"

# The named texture sets, as `bcfpipe train` source arguments (SEMANTIC=FILE:CHANNELS), and the
# folder each needs. brick is the grey base as one generic channel; bench_default_cost.py (and the
# scripts that take its SETS) train it as an rgb albedo instead.
SET_ARGS = {
    "teapot": [f"albedo={TEAPOT / 'tea_set_01_diff_2k.jpg'}:rgb", f"occlusion={TEAPOT / 'tea_set_01_arm_2k.jpg'}:r",
               f"roughness={TEAPOT / 'tea_set_01_arm_2k.jpg'}:g", f"metallic={TEAPOT / 'tea_set_01_arm_2k.jpg'}:b"],
    "brick": [f"generic={MX / 'brick' / 'brick_base_gray.jpg'}:r", f"normal={MX / 'brick' / 'brick_normal.jpg'}:xy",
              f"roughness={MX / 'brick' / 'brick_roughness.jpg'}:r"],
    # held out: a colour and a lone scalar (BC1 + BC4 in BC@R)
    "wood": [f"albedo={MX / 'wood' / 'wood_color.jpg'}:rgb", f"roughness={MX / 'wood' / 'wood_roughness.jpg'}:r"],
    # glTF's WaterBottle, 11 channels: base colour, normal, ORM, emissive
    "bottle": [f"albedo={BOTTLE / 'WaterBottle_baseColor.png'}:rgb", f"normal={BOTTLE / 'WaterBottle_normal.png'}:xy",
               f"occlusion={_ORM}:r", f"roughness={_ORM}:g", f"metallic={_ORM}:b",
               f"emissiveColor={BOTTLE / 'WaterBottle_emissive.png'}:rgb"],
}
_SET_DIRS = {"teapot": TEAPOT, "brick": MX / "brick", "wood": MX / "wood", "bottle": BOTTLE}


def needs(folder: Path) -> Path:
    """``folder`` when it is there; else exit with the message every script gives when the shared
    scenes are missing (they are not in the repository: ../shared/scenes or BCFPIPE_SCENES)."""
    if not folder.is_dir():
        raise SystemExit(f"needs the shared scenes at {SHARED}")
    return folder


def specs(name: str):
    """The TextureSpecs of a named set of SET_ARGS; exits on an unknown name or missing scenes."""
    from bcfpipe.texset.texture_set import TextureSpec

    if name not in SET_ARGS:
        raise SystemExit(f"unknown set {name!r}: teapot, brick, wood or bottle")
    needs(_SET_DIRS[name])
    return [TextureSpec.parse(s) for s in SET_ARGS[name]]


def spec_args(name: str) -> list[str]:
    """A named set as `bcfpipe train` arguments, written back from its parsed specs (canonical
    semantic names and channels), for the scripts that train it in a child process."""
    return [f"{s.semantic}={s.path}:{s.channels}" for s in specs(name)]


def machine() -> str:
    """CPU model, cores, and the GPU torch sees, for the record in docs/benchmarks.md."""
    from bcfpipe.bench.run import machine as record

    m = record()
    return f"{m['cpu']}, {m['cores']} cores, torch {m['torch']}, {m['gpu'] or 'no GPU'}"


def add_options(ap: argparse.ArgumentParser, **defaults) -> None:
    """Add ``--NAME`` options (``_`` in NAME written ``-``) with these defaults, in the order given:
    the --set, --profile, --preset, --features, --kernel, --seed, --reps... that most scripts take,
    so each script names only its defaults. An int or float default makes the option's type int or
    float; any other is taken as a string. Options with help text or choices are added as usual."""
    for name, default in defaults.items():
        kind = {"type": type(default)} if type(default) in (int, float) else {}
        ap.add_argument("--" + name.replace("_", "-"), default=default, **kind)


def run_bcfpipe(*args, lock: str | None = None, **kw) -> tuple[float, subprocess.CompletedProcess]:
    """`python -m bcfpipe ARGS` as a child process, output captured as text, timed from start to
    exit (import included, as a build system sees it): (wall seconds, the finished process; its
    ``args`` is the command). ``lock``: a file to hold with flock(1) for the run, so that on a
    machine shared with other jobs the runs take turns. ``kw`` goes to subprocess.run."""
    cmd = [sys.executable, "-m", "bcfpipe", *map(str, args)]
    if lock:
        cmd = ["flock", lock, *cmd]
    t = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, **kw)
    return time.perf_counter() - t, p


def mip_columns(mips) -> str:
    """The "mip k" headers of a per-mip table, " | "-joined: ``mips`` is a count or the indices."""
    return " | ".join(f"mip {k}" for k in (range(mips) if isinstance(mips, int) else mips))


def psnr_cells(per_mip, all_mips: float | None = None) -> str:
    """A per-mip table row's PSNR cells, " | "-joined: each mip to 0.1 dB, then (when given) the
    all-mips figure in bold to 0.01 dB, the shape of every per-mip table in docs/benchmarks.md."""
    cells = " | ".join(f"{v:.1f}" for v in per_mip)
    return cells if all_mips is None else cells + f" | **{all_mips:.2f}**"


# the line under a table of figures from train_material
PSNR_NOTE = "\n(PSNR in dB from the exported files; all mips: MSE averaged over the mips, as everywhere in bcfpipe)"


def bc_per_mip(ts, r: int) -> list[float]:
    """PSNR per reference mip of BC@r (bench's BC set: BC1/BC4/BC5, every mip encoded at ``r``),
    the classic row the per-mip tables compare against."""
    from bcfpipe.texset.baselines import encode_texture_set_baseline
    from bcfpipe.texset.metrics import mse_per_mip, psnr_from_mse
    from bcfpipe.texset.texture_set import build_mip_chain

    ref = build_mip_chain(ts.data)
    bc, _ = encode_texture_set_baseline(ts, "bc", r, ref_mips=ref)
    return [psnr_from_mse(m) for m in mse_per_mip(ref, bc, ts.channels)]


def write_json(path: Path | None, indent: int = 2, **fields) -> None:
    """A script's --json FILE, when given: ``fields`` after the machine they were measured on."""
    if path:
        Path(path).write_text(json.dumps({"machine": machine(), **fields}, indent=indent))
