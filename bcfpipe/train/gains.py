"""What a profile, a preset, a wider T_0 and a full training over the probe gain, in dB: the measured
tables rate control (`bcfpipe.fit.rate`) and the default layout (`bcfpipe.layout`) predict with.
Every figure is measured from exported files (docs/benchmarks.md names each benchmark)."""
from __future__ import annotations

__all__ = ["CPU_PROFILES", "GPU_PROFILES", "GAINS_DB", "T0_LAYER_GAINS_DB", "PROBE_GAINS_DB", "PROBE_GAINS_MAX_DB",
           "profile_gain", "probe_gains", "t0_layer_gains"]

# On a CPU, 2k does not pay for its 4x bytes and 2.4x time: on the teapot, 2k standard gave 38.54 dB
# at 7.08 MiB in 606 s, 1k standard 37.55 dB at 1.77 MiB in 256 s (docs/benchmarks.md).
CPU_PROFILES = ("0.5k", "1k")
GPU_PROFILES = ("0.5k", "1k", "2k")
# Mean PSNR over all mips relative to (0.5k, draft) on the teapot and the brick with the default
# features (bc7, a fixed T_0 of principal components; issue 52 measured them again: the table before
# held BC6H figures), `benchmarks/bench_presets.py --set S --profile P --features bc7`, each preset's
# schedule as config.PRESETS holds it (docs/benchmarks.md, "Issue 52: the gain table for bc7"):
#   teapot 34.68 / 35.65 / 35.88 (0.5k draft / fast / standard), 35.73 / 38.66 / 39.25 (1k)
#   brick  29.80 / 29.82 / 29.83, 31.48 / 31.55 / 31.59
# 2k is a candidate on CUDA only; its rows add the BC6H teapot's 2k standard over its 1k standard
# (+0.99 dB: 38.54 against 37.55, docs/benchmarks.md) to each 1k row: estimates until a GPU
# measures them.
GAINS_DB: dict[tuple[str, str], float] = {
    ("0.5k", "draft"): 0.0, ("0.5k", "fast"): 0.50, ("0.5k", "standard"): 0.62,
    ("1k", "draft"): 1.37, ("1k", "fast"): 2.87, ("1k", "standard"): 3.18,
    ("2k", "draft"): 2.36, ("2k", "fast"): 3.86, ("2k", "standard"): 4.17,
}
# What more layers of principal components in a fixed T_0 (--t0-layers, issue 52) add over one, in
# dB per reference mip, by the mip's place against T_0's level 0: the first entry for every mip
# finer than it (T_0 magnified), then level 0, 1, and the mean of every coarser one. Measured from
# exported files at 1k standard (the default preset), --layout neural, one thread,
# `benchmarks/bench_t0_widths.py --widths-only` (docs/benchmarks.md, "Issue 52: what auto ships"):
# two layers over one is the mean of the teapot (6 channels: +0.04 / +0.71 / +0.36, coarser +0.09
# … +1.5) and the water bottle (11: +0.29 / +2.92 / +1.81, coarser +0.35 … +3.1); three layers add
# the bottle's third over its second (+0.11 / -0.15 / -0.11, coarser -0.1 … -0.6) to that. A set of
# four channels or fewer has one layer only.
T0_LAYER_GAINS_DB: dict[int, tuple[float, ...]] = {
    1: (0.0, 0.0, 0.0, 0.0),
    2: (0.16, 1.81, 1.09, 0.62),
    3: (0.27, 1.66, 0.98, 0.24),
}
# What a full training at a preset gains over the default layout's probe (the same model trained for
# `layout.decide.PROBE_FRACTION` of its steps, issue 58), in dB per reference mip by its place against
# T_0's level 0, as T0_LAYER_GAINS_DB reads: finer than it, level 0, level 1, every coarser mip.
# Means over sets, from exported files, `benchmarks/bench_probe_gain.py --quality Q`
# (docs/benchmarks.md, "Issue 58: what a full training gains over the probe"):
#   draft: teapot, brick, wood, water bottle at 1k (per set, mip 0: 0.76 / 0.08 / 0.09 / 0.68;
#   mip 1: 1.44 / -0.24 / -0.09 / 2.06); standard: the teapot and the water bottle (mip 0: 0.55 /
#   0.50; mip 1: 0.19 / 2.09); fast: the teapot and the water bottle (mip 0: 1.35 / 0.60; mip 1:
#   2.33 / 2.41). paper (a GPU's) takes standard's until measured; smoke, a pipeline check, draft's.
PROBE_GAINS_DB: dict[str, tuple[float, float, float, float]] = {
    "draft": (0.41, 0.79, 0.82, 1.6),
    "fast": (0.97, 2.37, 2.52, 2.82),
    "standard": (0.53, 1.14, 1.48, 2.05),
}
# The most any of those sets gained, by the same places: a set's own gain at T_0's first levels
# ranges over 2 dB about the mean (the water bottle 2.1 dB at standard's mip 1, the teapot 0.2).
# A candidate that clears the floor only on these is the one the default layout trains when its
# mean prediction ships classic (`layout.decide`): on the bottle at 1k standard that training ships.
PROBE_GAINS_MAX_DB: dict[str, tuple[float, float, float, float]] = {
    "draft": (0.76, 2.06, 2.27, 2.34),
    "fast": (1.35, 2.41, 2.84, 3.86),
    "standard": (0.55, 2.09, 2.57, 2.12),
}
PAPER_OVER_STANDARD_DB = 1.0  # a GPU's 206k steps over `standard`'s 19.5k: a guess until measured on a GPU


def profile_gain(profile: str, preset: str) -> float:
    base = profile if (profile, "draft") in GAINS_DB else "0.5k"
    if preset == "paper":
        return GAINS_DB[(base, "standard")] + PAPER_OVER_STANDARD_DB
    return GAINS_DB[(base, preset)]


def probe_gains(preset: str, n_mips: int, t0_mip: int, most: bool = False) -> "list[float]":
    """`PROBE_GAINS_DB` of ``preset`` (``most``: `PROBE_GAINS_MAX_DB`) at each of ``n_mips``
    reference mips, T_0's level 0 serving reference mip ``t0_mip``."""
    table = PROBE_GAINS_MAX_DB if most else PROBE_GAINS_DB
    row = table.get(preset) or table["draft" if preset == "smoke" else "standard"]
    return [row[0] if k < t0_mip else row[min(1 + k - t0_mip, len(row) - 1)] for k in range(n_mips)]


def t0_layer_gains(t0_layers: int, n_mips: int, t0_mip: int) -> "list[float]":
    """`T0_LAYER_GAINS_DB` of ``t0_layers`` at each of ``n_mips`` reference mips, T_0's level 0
    serving reference mip ``t0_mip``."""
    row = T0_LAYER_GAINS_DB[t0_layers]
    return [row[0] if k < t0_mip else row[min(1 + k - t0_mip, len(row) - 1)] for k in range(n_mips)]
