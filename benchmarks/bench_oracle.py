"""Issue 58: the layout's oracle per T_0 size, compiled (`bcfpipe.layout.oracle_kernel`) against numpy.

For each set and each T_0 size a 2048² set weighs (1024 down to 16), in turn: the oracle as the layout
takes it (`oracle.magnified_errors`), and the same figures in numpy (the T_0-sized mip magnified
whole by `layout.classic.magnify`, read at the texels the oracle draws, measured by
`texset.metrics.mse_per_channel`); the fastest of ``--reps`` runs each, warm, one thread, and the
largest relative difference of the two, per channel and mip.

    python benchmarks/bench_oracle.py [--sets teapot,brick,wood,bottle] [--reps 3] [--json out.json]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, specs, write_json  # noqa: E402


def numpy_oracle(reference, t0: int, channels, wrap: str) -> np.ndarray:
    """`oracle.magnified_errors` in numpy: the whole magnified mip, read at the same drawn texels."""
    from bcfpipe.layout.classic import magnify
    from bcfpipe.layout.oracle import drawn_texels
    from bcfpipe.texset.metrics import mse_per_channel

    ref, masks = reference.mips, reference.masks
    j = max(0, (max(ref[0].shape[:2]) // t0).bit_length() - 1)
    picks = drawn_texels(reference.shapes[:j])
    e = np.zeros((len(ref), len(channels)))
    for k in range(min(j, len(ref))):
        h, w, c = ref[k].shape
        up = magnify(ref[j], h, w, wrap).reshape(-1, c)
        truth = ref[k].reshape(-1, c)
        at = np.arange(h * w) if picks[k] is None else picks[k]
        keep = None if masks is None else [masks[k].reshape(-1)[at][:, None]]
        e[k] = mse_per_channel([truth[at][:, None]], [up[at][:, None]], channels, keep)[0]
    return e


def best(fn, reps: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(reps):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="teapot,brick,wood,bottle")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    from bcfpipe.layout.oracle import magnified_errors
    from bcfpipe.texset.chain import Reference
    from bcfpipe.texset.texture_set import load_texture_set

    print(f"machine: {machine()}")
    rows = []
    for name in a.sets.split(","):
        ts = load_texture_set(specs(name))
        ref = Reference.of(ts, None, "repeat")
        magnified_errors(ref, 1024, ts.channels, "repeat")  # compiled or loaded from the cache
        for t0 in (1024, 512, 256, 128, 64, 32, 16):
            tk, ek = best(lambda: magnified_errors(ref, t0, ts.channels, "repeat"), a.reps)
            tn, en = best(lambda: numpy_oracle(ref, t0, ts.channels, "repeat"), a.reps)
            m = en > 0
            diff = float(np.max(np.abs(ek[m] - en[m]) / en[m])) if m.any() else 0.0
            rows.append(dict(set=name, t0=t0, compiled_s=round(tk, 4), numpy_s=round(tn, 4), max_rel_diff=diff))
            print(f"{name:7s} T_0 {t0:5d}: compiled {tk * 1e3:6.1f} ms, numpy {tn * 1e3:6.1f} ms, "
                  f"largest relative difference {diff:.1e}")
        total = [r for r in rows if r["set"] == name]
        print(f"{name:7s} all seven: compiled {sum(r['compiled_s'] for r in total):.2f} s, "
              f"numpy {sum(r['numpy_s'] for r in total):.2f} s")
    write_json(a.json, rows=rows)


if __name__ == "__main__":
    main()
