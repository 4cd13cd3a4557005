"""Wall time of `bcfpipe build` with --jobs 1 vs --jobs N on the sample scene (3 texture sets).

    .venv/bin/python benchmarks/bench_build_jobs.py [--jobs 1 2] [--repeat 1] [--profile tiny]
                                                    [--preset draft] [--scene samples/sample_scene.usda]

Each run is a full build (scan, training in worker processes, assembly) into a fresh temporary
folder; torch threads per worker are max(1, cores // jobs), as in a normal build. Prints the
machine, one line per run and a Markdown table for docs/benchmarks.md. The machine's load
average is printed before and after: on a shared machine, other work skews the numbers.
"""
from __future__ import annotations
from bcfpipe.builder import Execution

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, add_options  # noqa: E402


def machine() -> dict:
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import torch

    from bcfpipe import __version__
    from bcfpipe.builder import cpu_count

    return {"cpu": cpu, "cores": cpu_count(), "python": platform.python_version(), "torch": torch.__version__,
            "bcfpipe": __version__, "platform": platform.platform(),
            "loadavg": os.getloadavg() if hasattr(os, "getloadavg") else None}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=REPO / "samples" / "sample_scene.usda")
    ap.add_argument("--jobs", type=str, nargs="+", default=["1", "2"],
                    help="worker counts; JOBSxTHREADS (e.g. 1x1) also fixes torch threads per worker")
    add_options(ap, repeat=1, profile="tiny", preset="draft")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    args = ap.parse_args()

    from bcfpipe.builder import build
    from bcfpipe.config import TrainingOptions

    info = machine()
    if not args.json:
        print(f"machine: {info['cpu']}, {info['cores']} cores; torch {info['torch']}; bcfpipe {info['bcfpipe']}")
        print(f"load average before: {info['loadavg']}")
    configs = {}
    for spec in args.jobs:
        j, _, t = spec.partition("x")
        configs[spec] = (int(j), int(t) if t else max(1, info["cores"] // int(j)))
    runs: dict[str, list[float]] = {spec: [] for spec in configs}
    trained = None
    for r in range(args.repeat):
        for spec, (j, t) in configs.items():
            with tempfile.TemporaryDirectory(prefix="bcf-bench-") as tmp:
                t0 = time.perf_counter()
                res = build(args.scene, Path(tmp) / "out.bcf", execution=Execution(jobs=j), training=TrainingOptions(threads=t, profile=args.profile, preset=args.preset))
                wall = time.perf_counter() - t0
            if res.exit_code != 0:
                sys.exit(f"build failed: {res.failed}")
            trained = res.manifest.totals.trained
            runs[spec].append(wall)
            if not args.json:
                print(f"run {r + 1}: --jobs {j} ({t} torch thread(s) per worker): {wall:.1f} s wall "
                      f"({trained} texture sets)", flush=True)
    after = os.getloadavg() if hasattr(os, "getloadavg") else None
    base = statistics.median(runs[args.jobs[0]])
    result = {"machine": info, "loadavg_after": after, "scene": str(args.scene), "profile": args.profile,
              "preset": args.preset, "texture_sets": trained,
              "configs": {k: {"jobs": j, "threads": t} for k, (j, t) in configs.items()},
              "runs": runs,
              "median_s": {k: statistics.median(v) for k, v in runs.items()},
              "speedup": {k: base / statistics.median(v) for k, v in runs.items()}}
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"load average after: {after}")
    print()
    print("| --jobs | threads/worker | wall (median of %d) | speed-up |" % args.repeat)
    print("|---:|---:|---:|---:|")
    for spec, (j, t) in configs.items():
        print(f"| {j} | {t} | {result['median_s'][spec]:.1f} s | {result['speedup'][spec]:.2f}x |")


if __name__ == "__main__":
    main()
