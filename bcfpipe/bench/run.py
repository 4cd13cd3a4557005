"""`bcfpipe bench`: measure what each profile and preset buys against BC and ASTC, per texture set.

For every set: the baseline grid (BC@R with the BC7 quality set beside it, ASTC), then every
(profile, preset) BCf cell, then the decode cost of each BCf cell against the set's BC textures in
one GL run, and the crops. Every row carries its per-mip margins against BC@R and the BC7 quality
set at R (a BCf cell's R is its T_0 side: BC and the quality set are measured there too), and its
size twice: GPU bytes and zstd-19 bytes on disk (issue 52). The result is one JSON-ready dict
(bcfpipe.bench.report writes it with its plots, HTML and markdown).
"""
from __future__ import annotations

import os
import platform
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from bcfpipe import __version__
from bcfpipe.bench import cells as C
from bcfpipe.bench import crops as K
from bcfpipe.bench import lod_sweep as L
from bcfpipe.bench import decode_cost as D
from bcfpipe.bench.progress import BenchProgress, baseline_estimate, cell_estimate
from bcfpipe.bench.sets import BenchSet
from bcfpipe.config import PRESETS, resolve_profile
from bcfpipe.config import DEFAULT_HIDDEN, TrainingOptions
from bcfpipe.errors import InputError
from bcfpipe.errors import one_line
from bcfpipe.formats.sizes import DISK_ZSTD_LEVEL
from bcfpipe.formats.vocabulary import Layout
from bcfpipe.texset.baselines import BC7_QUALITY
from bcfpipe.texset.baselines import BC7_QUALITY, pack_texture_set
from bcfpipe.texset.reference import ReferencePyramid
from bcfpipe.texset.texture_set import build_mip_chain
from bcfpipe.verify import glsl as G
from bcfpipe.verify.targets import find_targets

__all__ = ["BenchOptions", "run_bench", "machine", "FORMAT", "FORMAT_VERSION"]

FORMAT = "bcfpipe-bench"
FORMAT_VERSION = 1
SIMILAR_SIZE = 2.0  # the crops' baseline: the best one within this factor of the BCf cell's size


@dataclass(frozen=True)
class BenchOptions:
    profiles: tuple[str, ...] = ("0.5k", "1k")
    presets: tuple[str, ...] = ("fast", "standard")
    features: tuple[str, ...] = ("bc6h",)  # feature formats: a cell per (profile, preset, format)
    codecs: tuple[str, ...] = ("bc", "astc")
    astc_blocks: tuple[str, ...] = ("4x4", "6x6", "8x8", "12x12")
    shifts: tuple[int, ...] = (0, 1)  # baselines at full and half resolution
    seed: int = 0
    device: str = "auto"
    threads: int = 1
    hidden: int | None = None
    decode_size: tuple[int, int] = (1920, 1080)
    decode_frames: int | None = None  # None: 100 on a GPU, 3 on a software renderer
    lod_step: float = 0.25
    keep_materials: bool = False


def machine() -> dict:
    """CPU, cores, torch and the GPU torch sees: the record every bench figure carries."""
    cpu = platform.processor() or "cpu"
    try:
        for line in subprocess.run(["lscpu"], capture_output=True, text=True).stdout.splitlines():
            if line.startswith("Model name:"):
                cpu = line.split(":", 1)[1].strip()
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "torch": torch.__version__,
            "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None}


def _check(bset: BenchSet, side: int, opts: BenchOptions) -> None:
    for p in opts.presets:
        if p not in PRESETS:
            raise InputError(f"unknown preset {p!r}; choose from {', '.join(PRESETS)}")
    for prof in opts.profiles:
        try:
            _, res = resolve_profile(prof, side)
        except ValueError as e:
            raise InputError(str(e)) from None
        if res[0] > side:
            raise InputError(f"{bset.name}: profile {prof} (T_0 = {res[0]}) is larger than its {side}-texel "
                             f"textures; pick smaller --profiles")


def _gl():
    try:
        return G.GLRuntime(), None
    except G.GLUnavailable as e:
        return None, str(e)


def _decode_costs(rt, bc: C.Cell | None, bcf: Sequence[C.Cell], opts: BenchOptions, wrap: str) -> dict:
    """Each BCf cell's full-screen decode against the set's own BC textures, in one GL context."""
    if bc is None or not bc.textures:
        return {"skipped": "no BC baseline in this bench (--baselines without bc)"}
    software = rt.is_software
    frames = opts.decode_frames or (3 if software else 100)
    warmup = 1 if software else 10
    try:
        names, fmts = D.upload_classic(rt, bc.textures, wrap)
        try:
            costs = D.measure(rt, [find_targets(c.folder)[0].desc for c in bcf], names, opts.decode_size,
                              frames, warmup)
        finally:
            rt.delete_textures(names)
    except Exception as exc:  # noqa: BLE001 - a GL failure costs this figure, not the bench

        return {"failed": one_line(exc)}
    rows = [{"method": cell.method, **c.to_json()} for cell, c in zip(bcf, costs)]
    return {"renderer": rt.info["renderer"], "gl_version": rt.info["version"], "software": software,
            "classic": bc.method, "classic_formats": fmts, "width": opts.decode_size[0],
            "height": opts.decode_size[1], "frames": frames, "timer": rows[0]["timer"] if rows else None,
            "rows": rows,
            "note": ("software renderer (llvmpipe): only the neural / classic ratio is meaningful"
                     if software else "GPU times from GL timer queries")}


def _similar_baseline(cell: C.Cell, baselines: Sequence[C.Cell]) -> C.Cell | None:
    near = [b for b in baselines if cell.size_bytes / SIMILAR_SIZE <= b.size_bytes <= cell.size_bytes * SIMILAR_SIZE]
    if near:
        return max(near, key=lambda b: b.metrics.psnr)
    return min(baselines, key=lambda b: abs(np.log(b.size_bytes / cell.size_bytes)), default=None)


def _grid(opts: BenchOptions, side: int) -> list[C.Baseline]:
    """The baselines of a set whose larger side is ``side``: the requested grid, with BC and the BC7
    quality set also at each profile's R (its T_0), which the BCf cells are reported against."""
    shifts = {(side // resolve_profile(p, side)[1][0]).bit_length() - 1 for p in opts.profiles} if opts.presets else ()
    return C.baseline_grid(opts.codecs, opts.astc_blocks, opts.shifts, sorted(shifts))


def _add_margins(rows: Sequence[C.Cell], baselines: Sequence[C.Cell]) -> None:
    """Each row's per-mip PSNR minus BC@R's and the BC7 quality set's at R (layout.json's keys:
    ``margin_per_mip_db``, ``margin_vs_bc7_per_mip_db``; ``against_bc``, ``against_bc7`` name
    them), R a BCf cell's T_0 side or a baseline's resolution; none against itself."""
    refs = (("margin_per_mip_db", "against_bc", "bc"), ("margin_vs_bc7_per_mip_db", "against_bc7", BC7_QUALITY))
    for r in rows:
        res = r.extra["resolutions"][0] if r.kind == "bcf" else r.extra["resolution"]
        for key, name, kind in refs:
            ref = next((b for b in baselines if b.kind == kind and b.extra["resolution"] == res), None)
            if ref is not None and ref is not r:
                r.extra[name] = ref.method
                r.extra[key] = [a - b for a, b in zip(r.metrics.psnr_per_mip, ref.metrics.psnr_per_mip)]


def _cell_options(opts: BenchOptions, profile: str, preset: str, features: str):
    """A BCf cell's training options: all neural, at ``profile`` and ``preset`` with ``features``."""
    return TrainingOptions(profile=profile, preset=preset, device=opts.device, seed=opts.seed,
                           hidden=opts.hidden or DEFAULT_HIDDEN, threads=opts.threads, features=features,
                           layout=Layout.NEURAL)


def bench_set(bset: BenchSet, ts, opts: BenchOptions, out: Path, work: Path, progress: BenchProgress, rt) -> dict:
    """Everything the report shows for one texture set (``ts``, loaded from ``bset``)."""
    ref = build_mip_chain(ts.data)
    grid = L.LodGrid(ReferencePyramid.from_mips(ref), bset.wrap, [c.peak for c in ts.channels], opts.lod_step)
    crop_at = K.crop_mips(len(ref))
    windows = [K.choose_window(ref, crop_at[0], K.CROP_MIP0), K.choose_window(ref, crop_at[1], K.CROP_MID)]
    trilinear = L.sweep(grid, L.mips_answer(ref, bset.wrap))
    side = max(ts.width, ts.height)

    baselines = []
    for b in _grid(opts, side):
        progress.start(f"{bset.name}: {b.label(side)}", _baseline_weight(ts, b))
        baselines.append(C.measure_baseline(ts, ref, b, grid, windows, tmp_dir=str(work)))
        progress.done()
    bcf: list[C.Cell] = []
    failed: list[dict] = []
    for prof in opts.profiles:
        for preset in opts.presets:
            for feat in opts.features:
                suffix = "" if feat == "bc6h" else f" {feat}"
                progress.start(f"{bset.name}: BCf {prof} {preset}{suffix}", _cell_weight(preset))
                folder = work / bset.slug / f"{prof}-{preset}{suffix.replace(' ', '-')}"
                try:
                    bcf.append(C.train_cell(ts, ref, _cell_options(opts, prof, preset, feat), folder, grid, windows,
                                            wrap=bset.wrap, progress=progress.fraction))
                except (FloatingPointError, RuntimeError, MemoryError) as exc:  # the other cells still count

                    failed.append({"method": f"BCf {prof} {preset}{suffix}", "error": one_line(exc)})
                progress.done()

    _add_margins([*baselines, *bcf], baselines)
    bc_full = next((b for b in baselines if b.kind == "bc" and b.extra["resolution"] == side), None)
    if rt is not None and bcf:
        progress.start(f"{bset.name}: decode cost", 1.0)
        decode = _decode_costs(rt, bc_full, bcf, opts, bset.wrap)
        progress.done()
    else:
        decode = {"skipped": "no OpenGL 4.5 context" if bcf else "no BCf cell"}

    crops = []
    best = max(bcf, key=lambda c: c.metrics.psnr, default=None)
    other = _similar_baseline(best, baselines) if best is not None else None
    for w, (mip, x, y, n) in enumerate(windows):
        methods = [(c.method, c.crops[w]) for c in (best, other) if c is not None]
        if not methods:
            break
        png = f"{bset.slug}_crop_mip{mip}.png"
        psnrs = K.crop_figure(out / png, f"{bset.name}, mip {mip} ({ref[mip].shape[1]}x{ref[mip].shape[0]}), "
                              f"{n}x{n} at ({x}, {y})", ts.channels, ref[mip][y:y + n, x:x + n], methods)
        crops.append({"mip": mip, "x": x, "y": y, "size": n, "png": png, "methods": [m for m, _ in methods],
                      "psnr": psnrs})

    if opts.keep_materials:
        keep = out / "materials" / bset.slug
        keep.parent.mkdir(parents=True, exist_ok=True)
        for c in bcf:
            dest = keep / c.folder.name
            if dest.exists():
                shutil.rmtree(dest)
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.replace(c.folder, dest)
            c.extra["folder"] = str(dest.relative_to(out))
    return {"name": bset.name, "slug": bset.slug, "sources": [str(s) for s in bset.display_specs()],
            "width": ts.width, "height": ts.height, "wrap": bset.wrap,
            "channels": [{"semantic": c.semantic, "kind": c.kind} for c in ts.channels],
            "mips": [list(m.shape[:2][::-1]) for m in ref],
            "baselines": [c.to_json() for c in baselines], "cells": [c.to_json() for c in bcf],
            "lod_sweep": {"s": grid.s, "trilinear_reference": trilinear, "points": int(grid.uv.shape[0])},
            "decode_cost": decode, "crops": crops, "failed": failed}


def _cell_weight(preset: str) -> float:
    p = PRESETS[preset]
    return cell_estimate(p.total_steps, p.batch)


def _baseline_weight(ts, b: C.Baseline) -> float:
    texels = (ts.width >> b.shift) * (ts.height >> b.shift)
    k = {"4x4": 4.0, "6x6": 2.0, "8x8": 1.5}.get(b.block or "", 1.0)  # astcenc -thorough slows with small blocks
    k *= 2.0 if b.codec == BC7_QUALITY else 1.0  # ISPC's BC7 against quicktex's BC1
    return baseline_estimate(len(pack_texture_set(ts, b.codec)), texels) * k


def run_bench(sets: Sequence[BenchSet], opts: BenchOptions, out: str | os.PathLike, quiet: bool = False) -> dict:
    """Bench every set into ``out`` (crop PNGs now; the caller writes the report)."""
    out = Path(out)
    loaded = []
    for s in sets:
        ts = s.load()
        _check(s, max(ts.width, ts.height), opts)
        loaded.append((s, ts))
    total = sum(sum(_baseline_weight(ts, b) for b in _grid(opts, max(ts.width, ts.height))) + 1.0 for _, ts in loaded)
    total += len(loaded) * len(opts.profiles) * len(opts.features) * sum(_cell_weight(p) for p in opts.presets)
    out.mkdir(parents=True, exist_ok=True)
    rt, gl_error = _gl() if opts.profiles and opts.presets else (None, None)
    results = []
    try:
        with tempfile.TemporaryDirectory(prefix=".bench-work-", dir=out) as work, \
                BenchProgress(total, quiet) as progress:
            for s, ts in loaded:
                results.append(bench_set(s, ts, opts, out, Path(work), progress, rt))
    finally:
        if rt is not None:
            rt.release()

    return {"format": FORMAT, "format_version": FORMAT_VERSION, "bcfpipe_version": __version__,
            "machine": machine(), "gl_error": gl_error,
            "options": {"profiles": list(opts.profiles), "presets": list(opts.presets), "features": list(opts.features),
                        "baselines": list(opts.codecs),
                        "astc_blocks": list(opts.astc_blocks), "baseline_scales": [1 / (1 << s) for s in opts.shifts],
                        "seed": opts.seed, "device": opts.device, "threads": opts.threads,
                        "lod_step": opts.lod_step, "disk_zstd_level": DISK_ZSTD_LEVEL},
            "sets": results}
