"""What measuring a material's mip 0 costs: SSIM and FLIP by bcfpipe's kernels (`texset.ssim`,
`texset.flip`) against the libraries they reproduce (scikit-image's ``structural_similarity``,
NVlabs' ``flip_evaluator``), on a real set, repetitions interleaved, each on one core and on every
core the machine has.

The decoded image is the reference plus noise of about 35 dB: the cost does not depend on the
error. Each library runs as bcfpipe ran it before issue 58's sixth stop: skimage per group, in bands
of rows, two groups side by side on threads; flip_evaluator per colour group in bands of rows, its
OpenMP threads as many as the cores. Prints each one's median seconds and how far its figures lie
from the library's.

  python benchmarks/bench_metrics.py [--set bottle] [--reps 3]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, specs  # noqa: E402

BAND = 1 << 22  # values per band, as bcfpipe banded both libraries
HALO = 32


def skimage_ssim(ref: np.ndarray, dec: np.ndarray, peak: float) -> float:
    """skimage's Gaussian SSIM of an (H, W, g) group, in bands of rows with a 5-row halo."""
    from skimage.metrics import structural_similarity

    h, w, g = ref.shape
    kw = dict(data_range=peak, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, full=True)
    rows, means = max(20, BAND // w), []
    for c in range(g):
        total = 0.0
        for y0 in range(5, h - 5, rows):
            y1 = min(h - 5, y0 + rows)
            a, b = max(0, y0 - 5), min(h, y1 + 5)
            _, s = structural_similarity(ref[a:b, :, c], dec[a:b, :, c], **kw)
            total += float(s[y0 - a:y1 - a, 5:w - 5].sum(dtype=np.float64))
        means.append(total / ((h - 10) * (w - 10)))
    return float(np.mean(means))


def evaluator_flip(ref: np.ndarray, dec: np.ndarray) -> float:
    """flip_evaluator's mean LDR-FLIP of an (H, W, 3) group, in bands of rows with a 32-row halo."""
    import flip_evaluator

    h, w = ref.shape[:2]
    rows, total = max(4 * HALO, BAND // (3 * w)), 0.0
    for y0 in range(0, h, rows):
        y1 = min(h, y0 + rows)
        a, b = max(0, y0 - HALO), min(h, y1 + HALO)
        err, _, _ = flip_evaluator.evaluate(np.clip(ref[a:b], 0, 1), np.clip(dec[a:b], 0, 1), "LDR", inputsRGB=True,
                                            applyMagma=False, computeMeanError=False)
        total += float(np.asarray(err)[y0 - a:y1 - a].sum(dtype=np.float64))
    return total / (h * w)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, set="bottle", reps=3)
    args = ap.parse_args()
    import torch

    from bcfpipe.texset import flip, parallel, ssim
    from bcfpipe.texset.texture_set import load_texture_set

    ts = load_texture_set(specs(args.set))
    ref = np.asarray(ts.data, np.float32)
    rng = np.random.default_rng(0)
    dec = (ref + rng.normal(0, 0.018, ref.shape)).astype(np.float32)
    groups: dict[str, list[int]] = {}
    for i, ch in enumerate(ts.channels):
        groups.setdefault(ch.semantic, []).append(i)
    colour = [g for g, idx in groups.items() if ts.channels[idx[0]].kind == "color" and len(idx) == 3]
    peaks = {g: ts.channels[idx[0]].peak for g, idx in groups.items()}
    cores = os.cpu_count() or 1
    print(f"machine: {machine()}; {args.set} {ts.width}x{ts.height}, {len(groups)} SSIM groups "
          f"({len(ts.channels)} channels), {len(colour)} FLIP groups; {args.reps} interleaved repetitions", flush=True)

    def libraries(n: int) -> tuple[list[float], list[float]]:
        torch.set_num_threads(n)  # flip_evaluator's OpenMP follows it
        with ThreadPoolExecutor(min(2, n)) as pool:
            s = list(pool.map(lambda g: skimage_ssim(ref[..., groups[g]], dec[..., groups[g]], peaks[g]), groups))
        return s, [evaluator_flip(ref[..., groups[g]], dec[..., groups[g]]) for g in colour]

    def kernels(n: int) -> tuple[list[float], list[float]]:
        parallel.set_encode_workers(n)
        try:
            s = [ssim.mean_ssim(ref[..., groups[g]], dec[..., groups[g]], peaks[g]) for g in groups]
            return s, [flip.mean_flip(ref[..., groups[g]], dec[..., groups[g]]) for g in colour]
        finally:
            parallel.set_encode_workers(None)

    kernels(1)  # compile (or load) the kernels outside the timings
    runs = {(who, n): [] for n in sorted({1, cores}) for who in ("libraries", "kernels")}
    figures = {}
    for _ in range(args.reps):
        for (who, n), times in runs.items():
            t = time.perf_counter()
            figures[who, n] = (libraries if who == "libraries" else kernels)(n)
            times.append(time.perf_counter() - t)
    print("\n| SSIM and FLIP of mip 0 | cores | seconds (median) | runs |\n|---|---:|---:|---|")
    for (who, n), times in runs.items():
        name = "skimage + flip_evaluator" if who == "libraries" else "bcfpipe's kernels"
        print(f"| {name} | {n} | {statistics.median(times):.2f} | {', '.join(f'{x:.2f}' for x in times)} |")
    (ls, lf), (ks, kf) = figures["libraries", cores], figures["kernels", cores]
    print(f"\nSSIM per group, largest difference: {max(abs(a - b) for a, b in zip(ls, ks)):.1e} "
          f"({', '.join(f'{g} {v:.6f}' for g, v in zip(groups, ks))})")
    if colour:
        print(f"FLIP per colour group, largest difference: {max(abs(a - b) for a, b in zip(lf, kf)):.1e} "
              f"({', '.join(f'{g} {v:.6f}' for g, v in zip(colour, kf))})")


if __name__ == "__main__":
    main()
